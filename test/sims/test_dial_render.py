"""Dial rendering: PNG encoding (always) and an EGL frame of the scene (skipped without EGL)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.data.episode import Episode
from sim_nodes.dial.render import RenderError, encode_png, project, save_episode, write_png
from sim_nodes.dial.scene import KEY_TOP_Z, KEY_XY, shared_model


def decode_png(data: bytes) -> np.ndarray:
    """Minimal decoder for the filter-0 RGB PNGs written by encode_png."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, size = 8, b"", (0, 0)
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        tag, payload = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        assert crc == zlib.crc32(tag + payload)
        if tag == b"IHDR":
            size = struct.unpack(">II", payload[:8])
        elif tag == b"IDAT":
            idat += payload
        pos += 12 + length
    w, h = size
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + 3 * w)
    assert np.all(raw[:, 0] == 0)
    return raw[:, 1:].reshape(h, w, 3)


def test_png_round_trip(tmp_path: Path) -> None:
    img = np.random.default_rng(0).integers(0, 256, (7, 11, 3), dtype=np.uint8)
    np.testing.assert_array_equal(decode_png(encode_png(img)), img)
    assert write_png(tmp_path / "a" / "x.png", img).read_bytes() == encode_png(img)
    with pytest.raises(RenderError, match="RGB"):
        encode_png(np.zeros((4, 4)))


def test_episode_without_joint_positions_is_rejected(tmp_path: Path) -> None:
    ep = Episode(observations=np.zeros((2, 39), np.float32), actions=np.zeros((1, 9), np.float32))
    with pytest.raises(RenderError, match="joint_position"):
        save_episode(ep, tmp_path / "never")
    assert not (tmp_path / "never").exists()


def test_render_scene_frame() -> None:
    import mujoco

    from sim_nodes.dial.render import make_renderer, render_frame

    dm = shared_model()
    data = mujoco.MjData(dm.model)
    mujoco.mj_forward(dm.model, data)
    try:
        renderer = make_renderer(dm.model, 160, 120)
    except RenderError as exc:
        pytest.skip(f"no offscreen GL here: {exc}")
    try:
        frame = render_frame(renderer, data)
    finally:
        renderer.close()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    u, v = project(data, dm.model, "main", np.array([[*KEY_XY[5], KEY_TOP_Z]]), 160, 120)[0]
    key_pixel = frame[int(v), int(u)].astype(int)
    assert key_pixel[0] > 120 and key_pixel[1] > 100 and key_pixel[2] < 90  # yellow key under the projection


def test_env_render_mode() -> None:
    from sim_nodes.dial.env import DialEnv

    env = DialEnv(render_mode="rgb_array")
    env.reset(seed=0)
    try:
        frame = env.render()
    except RenderError as exc:
        pytest.skip(f"no offscreen GL here: {exc}")
    finally:
        env.close()
    assert frame is not None and frame.shape == (480, 640, 3) and frame.std() > 10
    assert DialEnv().render() is None
