"""Episode markers as a typed message: ``ompn_interfaces/msg/EpisodeMarker`` on ``episode_marker``.

The codec round-trips every field; a bag with only typed markers (another lab's writer, the rosbags
one) splits into its episodes, as does a bag with only the deprecated ``DiagnosticArray`` markers; in
a bag with both the typed ones are read; ompn_node handles one of a marker's two forms, whichever
arrives first.  The sims' publication over DDS: ``test_sim_publishes_typed_markers`` (needs an
``ompn_interfaces`` built with the message).
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.reader import ReaderSpec, read_episodes
from ompn_ros.data.recorder.bag_writer import write_episodes
from ompn_ros.train.synthetic import make_dataset

ROOT = Path(__file__).resolve().parents[2]
STEP = 40_000_000


def test_typed_marker_round_trip_and_the_deprecated_form_read_alike() -> None:
    start = m.start_marker_values(3, "dial", 77, np.array([1, 2, 3, 4]))
    end = m.end_marker_values(3, "dial", 77, 120, True)
    for kind, values in (("start", start), ("end", end)):
        raw = m.encode_typed_marker(kind, 12_000_000_123, values)
        typed = m.parse_marker(raw, layout.EPISODE_MARKER_TYPE)
        legacy = m.parse_marker(m.encode_episode_marker(kind, 12_000_000_123, values))
        assert typed == legacy
    assert m.parse_typed_marker(m.encode_typed_marker("start", 5, start)) == (
        "start", {"episode": "3", "task": "dial", "seed": "77", "sketch": "1,2,3,4"})
    msg = m.deserialize(m.encode_typed_marker("end", 5_000_000_007, end), layout.EPISODE_MARKER_TYPE)
    fields = (msg.kind, msg.episode, msg.task, msg.seed, msg.steps, msg.success)
    assert fields == (1, 3, "dial", 77, 120, True)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (5, 7) and list(msg.sketch) == []


def _lab_bag(path: Path, typed: bool, legacy: bool, episodes: int = 3, steps: int = 6) -> None:
    """A bag as another lab writes it (rosbags' writer): Float32MultiArray observations and actions and
    the markers in the forms asked for, 2 s between episodes."""
    store = m.register_interfaces()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        obs = writer.add_connection("/observation", layout.FLOAT32_ARRAY, typestore=store)
        act = writer.add_connection("/action", layout.FLOAT32_ARRAY, typestore=store)
        new = writer.add_connection("/episode_marker", layout.EPISODE_MARKER_TYPE, typestore=store) \
            if typed else None
        old = writer.add_connection("/episode", layout.DIAGNOSTIC_ARRAY, typestore=store) if legacy else None
        for ep in range(episodes):
            t0 = 1_000_000_000 + ep * 2_000_000_000
            ends = (("start", t0, m.start_marker_values(ep, "lab", 100 + ep, None)),
                    ("end", t0 + (steps + 1) * STEP + 1,
                     m.end_marker_values(ep, "lab", 100 + ep, steps, True)))
            for kind, stamp, values in ends[:1]:
                _markers(writer, new, old, kind, stamp, values)
            for t in range(steps + 1):
                stamp = t0 + (t + 1) * STEP
                writer.write(obs, stamp, m.encode_float32_array(np.full(4, t + 10 * ep, np.float32), "obs"))
                if t < steps:
                    writer.write(act, stamp + 1, m.encode_float32_array(np.full(2, t, np.float32), "act"))
            for kind, stamp, values in ends[1:]:
                _markers(writer, new, old, kind, stamp, values)


def _markers(writer: Writer, new: object, old: object, kind: str, stamp: int, values: dict) -> None:
    if new is not None:
        writer.write(new, stamp, m.encode_typed_marker(kind, stamp, values))
    if old is not None:
        writer.write(old, stamp, m.serialize(m.episode_marker(kind, stamp, values)))


def _spec() -> ReaderSpec:
    return ReaderSpec.from_dict({"observation": {"topic": "observation"}, "action": {"topic": "action"},
                                 "subtask": None, "sketch": None, "split": "markers"})


@pytest.mark.parametrize(("typed", "legacy"), [(True, False), (False, True), (True, True)])
def test_the_reader_splits_on_either_form(tmp_path: Path, typed: bool, legacy: bool) -> None:
    """Before: a bag with only typed markers was refused (the markers' topic 'episode' is required)."""
    _lab_bag(tmp_path / "bag", typed, legacy)
    result = read_episodes(tmp_path / "bag", spec=_spec())
    assert [ep.length for ep in result.episodes] == [6, 6, 6]
    assert [ep.seed for ep in result.episodes] == [100, 101, 102]


def test_typed_markers_are_the_ones_read_when_a_bag_has_both(tmp_path: Path) -> None:
    """bag_recorder records both forms of the sims' markers for one release; the reader takes the typed
    ones (the deprecated ones here name other seeds, so a mix-up shows)."""
    store = m.register_interfaces()
    _lab_bag(tmp_path / "bag", typed=True, legacy=False)
    with Writer(tmp_path / "both", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        from rosbags.highlevel import AnyReader

        with AnyReader([tmp_path / "bag"]) as reader:
            conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=store)
                     for c in reader.connections}
            old = writer.add_connection("/episode", layout.DIAGNOSTIC_ARRAY, typestore=store)
            for conn, stamp, raw in reader.messages():
                writer.write(conns[conn.topic], stamp, raw)
                if conn.topic == "/episode_marker":
                    kind, values = m.parse_typed_marker(raw)
                    writer.write(old, stamp, m.encode_episode_marker(kind, stamp, {**values, "seed": "9"}))
    assert [ep.seed for ep in read_episodes(tmp_path / "both", spec=_spec()).episodes] == [100, 101, 102]


def test_ompn_collect_bags_carry_typed_markers_and_read_back(tmp_path: Path) -> None:
    episodes = make_dataset("craft_shaped", 2, seed=0)
    stats = write_episodes(tmp_path / "bag", episodes, "craft")
    assert stats.messages["/episode_marker"] == 4 and "/episode" not in stats.messages
    back = read_episodes(tmp_path / "bag").episodes
    assert [ep.length for ep in back] == [ep.length for ep in episodes]


def test_node_keeps_one_of_a_markers_two_forms() -> None:
    pytest.importorskip("rclpy")
    from ompn_ros.nodes.ompn_node_markers import MarkerTwins

    twins = MarkerTwins()
    start = {"episode": "0", "task": "dial", "seed": "5", "sketch": "1,2"}
    assert twins.keep(False, "start", start)  # the deprecated twin came first
    assert not twins.keep(True, "start", start)  # its typed twin: dropped
    assert twins.keep(True, "start", start)  # a restarted publisher's same start: handled
    assert not twins.keep(False, "start", start)
    end = {"episode": "0", "task": "dial", "seed": "5", "steps": "9", "success": "true"}
    assert twins.keep(True, "end", end) and twins.keep(True, "start", {**start, "episode": "1"})
    assert twins.typed_seen and twins.deprecated_handled == 1


SUBSCRIBER = """
import os, sys, time
import rclpy
from ompn_interfaces.msg import EpisodeMarker
rclpy.init()
node = rclpy.create_node("marker_probe")
got = []
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
node.create_subscription(EpisodeMarker, "episode_marker", got.append, qos)
sim = __import__("subprocess").Popen([sys.executable, "-m", "sim_nodes.dial.node", "--ros-args", "-p",
                                      "episodes:=1", "-p", "rate:=200.0", "-p", "wait_for_subscribers:=1",
                                      "-p", "wait_topics:=[episode_marker]"])
deadline = time.monotonic() + 60
while len(got) < 2 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
sim.terminate(); sim.wait(timeout=20)
print([(g.kind, g.episode, g.task, len(g.sketch), g.steps) for g in got])
"""


def test_sim_publishes_typed_markers(ros_env: dict[str, str]) -> None:
    probe = subprocess.run([sys.executable, "-c", "from ompn_interfaces.msg import EpisodeMarker"],
                           env=ros_env, capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip("ompn_interfaces was built before EpisodeMarker: rebuild it (build_venv.py)")
    done = subprocess.run([sys.executable, "-c", SUBSCRIBER], env={**ros_env, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), ros_env.get("PYTHONPATH", "")])}, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    got = ast.literal_eval(done.stdout.strip().splitlines()[-1])
    assert [(kind, episode, task) for kind, episode, task, _, _ in got] == [(0, 0, "dial"), (1, 0, "dial")]
    assert got[0][3] == 4 and got[1][4] > 0  # the start's sketch, the end's steps
