"""Streams the way real drivers publish them, for ompn_node in process and the bag reader's rules."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState  # noqa: E402

from ompn_ros.data import ReaderSpec, read_episodes  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

ARM, GRIPPER = ["j1", "j2", "j3"], ["finger"]
NOW_S = 1_700_000_000  # header stamps near wall time (the node's stamp checks stay on)


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    out = {}
    for dim in (3, 4):
        torch.manual_seed(dim)
        cfg = OMPNConfig(obs_dim=dim, action_type="continuous", action_dim=3, n_slots=3, slot_size=16)
        out[dim] = tmp_path_factory.mktemp("streams") / f"ckpt{dim}"
        save_checkpoint(out[dim], OMPNPolicy(cfg))
    return out


def msg(head: int, names: list[str], position: Any, velocity: Any = ()) -> JointState:
    out = JointState(name=names, position=[float(v) for v in position], velocity=[float(v) for v in velocity])
    out.header.stamp.sec, out.header.stamp.nanosec = divmod(head, S)
    return out


def events(node: Any) -> list[tuple[int, str, int, str]]:
    out = []
    for raw in node.outputs.pubs["boundary"].raws:
        b = decode_subtask_boundary(raw)
        out.append((b.step, f"{b.score:.6f}", b.stamp_ns, str(b.final).lower()))
    return out


def replay(ckpt: Path, obs: np.ndarray, stamps: np.ndarray) -> list[tuple[int, str, int, str]]:
    """A fresh replay of one episode as the reader gives it: every row stepped (row T too, as live),
    the last segment closed at T - 1."""
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig(high=0.3, low=0.3))
    seg.reset(None)
    out = [e for x, s in zip(obs, stamps, strict=True) if (e := seg.step(x, int(s)).boundary) is not None]
    out = out + seg.end_episode(len(obs) - 2)  # every episode ends with one final event
    return [(e.step, f"{e.score:.6f}", e.stamp_ns, str(e.final).lower()) for e in out]


def _idle_stream(rng: np.random.Generator) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(header stamp, position, velocity) at 50 Hz: 1 s still, a demonstration, 1 s still, another, 1 s
    still; encoder noise throughout."""
    out, pos, t = [], rng.normal(size=3), NOW_S * S
    for n in (0, 16, 12):
        for _ in range(n):
            vel = rng.uniform(0.3, 1.0, 3) * rng.choice([-1, 1], 3)
            out.append((t, pos + rng.normal(scale=1e-7, size=3), vel))
            pos, t = pos + vel * 0.02, t + 20 * MS
        for _ in range(50):
            out.append((t, pos + rng.normal(scale=1e-7, size=3), np.zeros(3)))
            t += 20 * MS
    return out


def idle_bag(tmp_path: Path, seed: int) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], Any]:
    """A driver's stream that idles between demonstrations, recorded into a bag and read with
    ``split: idle``: (the stream, the reader's result)."""
    stream = _idle_stream(np.random.default_rng(seed))
    bag = BagWriter(tmp_path / "bag")
    for head, pos, vel in stream:
        bag.add("/joint_states", JOINT_STATE, head + 2 * MS, joint_state(head, ARM, pos, vel), BEST_EFFORT)
    bag.write()
    spec = ReaderSpec.from_dict({
        "observation": {"topic": "/joint_states", "type": JOINT_STATE, "fields": ["position"]},
        "action": {"topic": "/joint_states", "type": JOINT_STATE, "fields": ["velocity"]},
        "subtask": None, "sketch": None, "episode": None, "stamp": "header", "split": "idle",
        "idle_s": 0.5, "idle_speed": 0.01, "final_observation": "drop_last_step"})
    return stream, read_episodes(tmp_path / "bag", spec=spec)


def stream_pos(stream: list[tuple[int, np.ndarray, np.ndarray]]) -> np.ndarray:
    return np.asarray([p for _, p, _ in stream], dtype=np.float32)
