"""Offscreen rendering of the Dial scene: PNG stills, PNG frame sequences and (with ffmpeg) MP4.

Rendering uses MuJoCo's EGL backend (``MUJOCO_GL=egl``, set by ``sim_nodes.dial`` before mujoco
is imported).  When no GL context can be created, :class:`RenderError` says what to install or
set.  MP4 is written only when an ``ffmpeg`` executable is on ``PATH``; otherwise the episode is
saved as numbered PNG frames.  PNGs are encoded here with ``zlib`` (no imaging dependency).

CLI (``render_cli.py``)::

    python -m sim_nodes.dial.render_cli --scene docs/dial_scene.png
    python -m sim_nodes.dial.render_cli --episode 3 --out out/dial_ep3   # frames (or .mp4)
    python -m sim_nodes.dial.render_cli --episode 3 --out out/dial_ep3 --strip docs/dial_presses.png
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import mujoco
import numpy as np

from ompn_ros.data.episode import Episode
from sim_nodes.dial.scene import KEY_TOP_Z, KEY_XY, N_KEYS, shared_model
from sim_nodes.dial.targets import shared_targets

WIDTH, HEIGHT = 640, 480


class RenderError(RuntimeError):
    """Offscreen rendering is unavailable or was asked for something impossible."""


def make_renderer(model: mujoco.MjModel, width: int = WIDTH, height: int = HEIGHT) -> mujoco.Renderer:
    """An offscreen renderer; raises :class:`RenderError` with a hint when GL is missing."""
    backend = os.environ.get("MUJOCO_GL", "")
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # EGL/GL failures surface as several exception types
        raise RenderError(
            f"cannot create an offscreen MuJoCo renderer (MUJOCO_GL={backend!r}): {exc}. "
            "Install EGL (Debian: libegl1, libgl1) and set MUJOCO_GL=egl before importing mujoco; "
            "OSMesa (MUJOCO_GL=osmesa) is the software fallback."
        ) from exc


def render_frame(renderer: mujoco.Renderer, data: mujoco.MjData, camera: str = "main") -> np.ndarray:
    """RGB uint8 image [H, W, 3] of ``data`` seen from ``camera``."""
    renderer.update_scene(data, camera=camera)
    return np.asarray(renderer.render(), dtype=np.uint8).copy()


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB uint8 image [H, W, 3]."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise RenderError(f"encode_png expects an RGB image [H, W, 3], got shape {img.shape}")
    h, w, _ = img.shape
    raw = b"".join(b"\x00" + img[row].tobytes() for row in range(h))

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


def write_png(path: str | Path, image: np.ndarray) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode_png(image))
    return path


def project(data: mujoco.MjData, model: mujoco.MjModel, camera: str, points: np.ndarray,
            width: int, height: int) -> np.ndarray:  # fmt: skip
    """Pixel coordinates (u, v) of world ``points`` [N, 3] in ``camera``'s image."""
    cam = model.camera(camera).id
    rot = data.cam_xmat[cam].reshape(3, 3)
    local = (np.asarray(points) - data.cam_xpos[cam]) @ rot
    focal = 0.5 * height / np.tan(np.radians(model.cam_fovy[cam]) / 2)
    depth = -local[:, 2]
    u = width / 2 + focal * local[:, 0] / depth
    return np.stack([u, height / 2 - focal * local[:, 1] / depth], axis=1)


def save_scene_png(path: str | Path, qpos: np.ndarray | None = None, *, label_keys: bool = True) -> Path:
    """Render the scene (home pose by default) to ``path``, digits annotated with matplotlib."""
    dm = shared_model()
    data = mujoco.MjData(dm.model)
    data.qpos[dm.qpos_adr] = shared_targets().home if qpos is None else qpos
    mujoco.mj_forward(dm.model, data)
    renderer = make_renderer(dm.model, 800, 600)
    try:
        image = render_frame(renderer, data)
    finally:
        renderer.close()
    if not label_keys:
        return write_png(path, image)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = np.array([[*KEY_XY[d], KEY_TOP_Z] for d in range(N_KEYS)])
    uv = project(data, dm.model, "main", centres, 800, 600)
    fig = plt.figure(figsize=(8, 6), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(image)
    for digit, (u, v) in enumerate(uv):
        ax.text(u, v, str(digit), color="firebrick", fontsize=18, fontweight="bold", ha="center", va="center")
    ax.set_axis_off()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def render_episode(episode: Episode, *, every: int = 1, camera: str = "main") -> list[np.ndarray]:
    """Frames of an episode replayed from its ``joint_position`` extras (kinematic replay)."""
    if "joint_position" not in episode.extras:
        raise RenderError(f"episode (seed {episode.seed}) has no 'joint_position' extras to replay")
    dm = shared_model()
    data = mujoco.MjData(dm.model)
    renderer = make_renderer(dm.model)
    frames = []
    try:
        for q in np.asarray(episode.extras["joint_position"])[::every]:
            data.qpos[dm.qpos_adr] = q
            mujoco.mj_forward(dm.model, data)
            frames.append(render_frame(renderer, data, camera))
    finally:
        renderer.close()
    return frames


def save_episode(episode: Episode, out: str | Path, *, every: int = 1, fps: float = 25.0) -> list[Path]:
    """Write an episode as ``out.mp4`` if ffmpeg exists, else ``out/frame_00000.png`` ...

    Returns the written paths.
    """
    frames = render_episode(episode, every=every)
    out = Path(out)
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is not None:
        mp4 = out.with_suffix(".mp4")
        mp4.parent.mkdir(parents=True, exist_ok=True)
        h, w, _ = frames[0].shape
        cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
               "-r", str(fps / every), "-i", "-", "-pix_fmt", "yuv420p", str(mp4)]  # fmt: skip
        subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), check=True)
        return [mp4]
    return [write_png(out / f"frame_{i:05d}.png", f) for i, f in enumerate(frames)]


def save_press_strip(episode: Episode, path: str | Path) -> Path:
    """One image per press (the step that completes each subtask), side by side, titled by digit."""
    if episode.subtask is None or "joint_position" not in episode.extras:
        raise RenderError(f"episode (seed {episode.seed}) needs subtask labels and 'joint_position' extras")
    dm = shared_model()
    data = mujoco.MjData(dm.model)
    renderer = make_renderer(dm.model, 400, 300)
    frames = []
    try:
        for t in episode.boundaries:
            data.qpos[dm.qpos_adr] = episode.extras["joint_position"][t + 1]
            mujoco.mj_forward(dm.model, data)
            frames.append(render_frame(renderer, data, "side"))
    finally:
        renderer.close()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(frames), figsize=(4 * len(frames), 3.3), dpi=100)
    sketch = [] if episode.sketch is None else episode.sketch.tolist()
    for k, (ax, frame, t) in enumerate(zip(np.atleast_1d(axes), frames, episode.boundaries, strict=True)):
        ax.imshow(frame)
        ax.set_title(f"subtask {k}: press {sketch[k] if k < len(sketch) else '?'} (step {t})")
        ax.set_axis_off()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
