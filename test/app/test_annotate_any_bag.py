"""``ompn_segment --annotate`` on the bags another lab records: JointState observations with header
stamps, an ``assemble:`` spec of several topics; the annotated copy says ``ros_distro: jazzy`` and
offers each added topic with the node's QoS, so a player that honours ``offered_qos_profiles`` (as
``ros2 bag play`` does) delivers its boundaries to ``examples/subtask_progress.py``'s TRANSIENT_LOCAL
subscription; ``subtask_id`` comes from the episode's sketch; offline outputs carry stamps."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("torch")

from driver_bags import MS, BagWriter, joint_state, scalar
from rosbags.highlevel import AnyReader

from ompn_ros import layout
from ompn_ros.cli.segment import main
from ompn_ros.data.messages import EPISODE_END, SUBTASK_END, decode_subtask_boundary
from ompn_ros.train import synthetic

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "subtask_progress.py"
BOUNDARY = "/ompn_node/boundary"
STEP_MS = 20  # 50 Hz, another lab's driver


def _arm_bag(path: Path, episodes: list) -> list[np.ndarray]:
    """The synthetic episodes as an arm would record them: the observation as the positions of a
    JointState (header stamps on the robot's clock, 3 ms before the bag's receive stamps), one Int32
    command per step, the first element again on a second topic, 2 s of silence between episodes;
    the receive stamps of each episode's observations."""
    bag = BagWriter(path)
    names = [f"j{i}" for i in range(episodes[0].observations.shape[1])]
    t, stamps = 10_000 * MS, []
    for ep in episodes:
        got = []
        for row, obs in enumerate(ep.observations):
            bag.add(
                "/arm/joint_states",
                "sensor_msgs/msg/JointState",
                t,
                joint_state(t - 3 * MS, names, position=obs.astype(np.float64)),
            )
            bag.add(
                "/arm/first", "std_msgs/msg/Float32", t - MS, scalar("std_msgs/msg/Float32", float(obs[0]))
            )
            if row < ep.length:
                bag.add(
                    "/arm/command",
                    "std_msgs/msg/Int32",
                    t + 2 * MS,
                    scalar("std_msgs/msg/Int32", int(ep.actions[row])),
                )
            got.append(t)
            t += STEP_MS * MS
        stamps.append(np.array(got, dtype=np.int64))
        t += 2000 * MS
    bag.write()
    return stamps


def _spec(path: Path, assemble: bool) -> Path:
    observation = (
        {"assemble": {"step_topic": "joint_states", "tolerance_s": 0.01, "stamp": "receive", "fields": [
            {"topic": "joint_states", "type": "sensor_msgs/msg/JointState", "field": "position"},
            {"topic": "first", "type": "std_msgs/msg/Float32", "field": "data"}]}}
        if assemble else
        {"observation": {"topic": "joint_states", "type": "sensor_msgs/msg/JointState",
                         "fields": ["position"]}, "stamp": "header"})  # fmt: skip
    doc = {
        "reader": {
            "namespace": "/arm",
            **observation,
            "action": {"topic": "command", "type": "std_msgs/msg/Int32"},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "joint_states": None,
            "split": "gaps",
            "time_gap": 1.0,
            "tolerance": 0.01,
            "final_observation": "duplicate",
        }
    }
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("assemble", [False, True], ids=["joint_state", "assembled"])
def test_annotate_reads_the_stamps_of_any_observation(
    tmp_path: Path, synthetic_checkpoint: Path, assemble: bool
) -> None:
    """Before: exit 2, "observations are 'sensor_msgs/msg/JointState', not Float32MultiArray" or
    "topic '/arm/observation' ... not in the bag"; the annotated bag was never written."""
    episodes = synthetic.make_dataset("discrete", 3, seed=7)
    stamps = _arm_bag(tmp_path / "bag", episodes)
    spec = _spec(tmp_path / "spec.yaml", assemble)
    out = tmp_path / "annotated"
    checkpoint = synthetic_checkpoint if not assemble else _wider(tmp_path, synthetic_checkpoint)
    code = main(
        [
            "--bag",
            str(tmp_path / "bag"),
            "--reader-config",
            str(spec),
            "--checkpoint",
            str(checkpoint),
            "--out",
            str(tmp_path / "seg"),
            "--plot-episodes",
            "0",
            "--annotate",
            str(out),
        ]
    )
    assert code == 0
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == BOUNDARY]
        events = [(t, raw) for c, t, raw in reader.messages(connections=conns)]
        pis = [
            t for c, t, _ in reader.messages([c for c in reader.connections if c.topic == "/ompn_node/pi"])
        ]
    assert set(pis) <= {int(s) for st in stamps for s in st}  # at the observations' receive stamps
    decoded = [decode_subtask_boundary(raw) for _, raw in events]
    for number in range(1, len(episodes) + 1):
        mine = [b for b in decoded if b.episode == number]
        assert [b.final for b in mine] == [False] * (len(mine) - 1) + [True]
        ends = [b for b in mine if b.kind == SUBTASK_END]
        assert [b.subtask for b in ends] == list(range(len(ends)))
        assert all(b.kind == EPISODE_END for b in mine[len(ends) :])
        assert all(b.stamp_ns in set(stamps[number - 1].tolist()) for b in ends)
    doc = json.loads((tmp_path / "seg" / "boundaries.json").read_text())  # stamps, not only steps
    for ep_doc, st in zip(doc["episodes"], stamps, strict=True):
        assert [b["stamp_ns"] for b in ep_doc["boundaries"]] == [
            int(st[b["step"]]) for b in ep_doc["boundaries"]
        ]


def _wider(tmp_path: Path, checkpoint: Path) -> Path:
    """A model of the assembled observation (positions, then the first element again)."""
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.train import trainer
    from ompn_ros.train.config import TrainConfig

    data = [
        type(ep)(
            observations=np.concatenate([ep.observations, ep.observations[:, :1]], axis=1),
            actions=ep.actions,
            subtask=ep.subtask,
            sketch=ep.sketch,
        )
        for ep in synthetic.make_dataset("discrete", 16, seed=0)
    ]
    obs_dim, action_type, action_dim, _ = synthetic.synthetic_spec("discrete")
    cfg = OMPNConfig(
        obs_dim=obs_dim + 1, action_type=action_type, action_dim=action_dim, n_slots=3, slot_size=16
    )
    trainer.train(
        data,
        cfg,
        TrainConfig(iterations=5, batch_size=8, eval_every=5, out_dir=str(tmp_path / "wide"), progress=False),
    )
    return tmp_path / "wide" / "best"


def test_annotated_bags_replay_to_the_shipped_consumer(
    tmp_path: Path, synthetic_checkpoint: Path, ros_env: dict[str, str]
) -> None:
    """Jazzy metadata, the node's QoS on each added topic, ``subtask_id`` from the sketch; a player
    honouring ``offered_qos_profiles`` delivers every boundary to the example.  Before: ``ros_distro:
    rosbags``, no offered QoS (a player offers VOLATILE: the example's TRANSIENT_LOCAL subscription
    matches nothing), ``subtask_id`` -1."""
    from ompn_ros.data.recorder.bag_writer import write_episodes

    episodes = [
        ep.__class__(**{**ep.__dict__, "sketch": np.array([7, 3, 5, 2, 6][: len(ep.boundaries)])})
        for ep in synthetic.make_dataset("discrete", 3, seed=9)
    ]
    domain = layout.DomainLayout(**{**layout.CRAFT.__dict__, "obs_dim": episodes[0].observations.shape[1]})
    write_episodes(tmp_path / "bag", episodes, domain)
    out = tmp_path / "annotated"
    assert (
        main(
            [
                "--bag",
                str(tmp_path / "bag"),
                "--checkpoint",
                str(synthetic_checkpoint),
                "--out",
                str(tmp_path / "seg"),
                "--plot-episodes",
                "0",
                "--annotate",
                str(out),
            ]
        )
        == 0
    )
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["ros_distro"] == "jazzy"
    offered = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in meta["topics_with_message_count"]
    }
    boundary_qos = offered[BOUNDARY][0] if isinstance(offered[BOUNDARY], list) else offered[BOUNDARY]
    assert "transient_local" in json.dumps(boundary_qos).lower() or "durability: 1" in str(boundary_qos)
    with AnyReader([out]) as reader:
        raws = [raw for c, _, raw in reader.messages([c for c in reader.connections if c.topic == BOUNDARY])]
    msgs = [decode_subtask_boundary(raw) for raw in raws]
    for b in msgs:
        sketch = episodes[b.episode - 1].sketch
        want = int(sketch[b.subtask]) if b.kind == SUBTASK_END and b.subtask < len(sketch) else -1
        assert b.subtask_id == want
    assert any(b.subtask_id >= 0 for b in msgs)
    lines = _play_to_example(out, ros_env)
    done = [line for line in lines if " done at step " in line]
    finished = [line for line in lines if " finished: " in line]
    assert len(done) == sum(b.kind == SUBTASK_END for b in msgs) and len(finished) == len(episodes), lines


PLAYER = """
import sys, time
import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from ompn_interfaces.msg import SubtaskBoundary

# a player as `ros2 bag play` is: each topic offered with the QoS the bag says it was offered with
bag, topic = sys.argv[1], sys.argv[2]
rclpy.init()
node = rclpy.create_node("bag_player")
with Reader(bag) as reader:
    conn = next(c for c in reader.connections if c.topic == topic)
    qos = conn.ext.offered_qos_profiles[0]
    profile = QoSProfile(depth=qos.depth, history=HistoryPolicy(qos.history.value),
                         reliability=ReliabilityPolicy(qos.reliability.value),
                         durability=DurabilityPolicy(qos.durability.value))
    raws = [bytes(raw) for _, _, raw in reader.messages(connections=[conn])]
pub = node.create_publisher(SubtaskBoundary, topic, profile)
deadline = time.monotonic() + 60
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
for raw in raws:
    pub.publish(raw)
    time.sleep(0.01)
time.sleep(1.0)
print(len(raws), pub.get_subscription_count(), flush=True)
"""


def _play_to_example(bag: Path, env: dict[str, str]) -> list[str]:
    from node_process import NodeProcess

    topic = f"/play_{os.getpid()}/boundary"  # unique: the DDS domain may be shared
    renamed = _renamed(bag, topic)
    example = NodeProcess(env, f"boundary_topic:={topic}", program=[sys.executable, str(EXAMPLE)])
    try:
        time.sleep(1.0)
        played = subprocess.run(
            [sys.executable, "-c", PLAYER, str(renamed), topic],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert played.returncode == 0, played.stdout + played.stderr
    finally:
        out = example.stop()
    return out.splitlines()


def _renamed(bag: Path, topic: str) -> Path:
    """The annotated bag's boundary topic under a name of this test's own (its QoS and bytes kept)."""
    from rosbags.rosbag2 import Reader, Writer

    out = bag.parent / "renamed"
    with Reader(bag) as reader, Writer(out, version=9) as writer:
        conn = next(c for c in reader.connections if c.topic == BOUNDARY)
        new = writer.add_connection(
            topic,
            conn.msgtype,
            msgdef=conn.msgdef.data,
            rihs01=conn.digest,
            offered_qos_profiles=conn.ext.offered_qos_profiles,
        )
        for _, stamp, raw in reader.messages(connections=[conn]):
            writer.write(new, stamp, raw)
    return out


def test_every_episode_is_in_the_segments_table(tmp_path: Path) -> None:
    """An episode without a boundary is one row; the last subtask ends at the episode's last step."""
    from ompn_ros.app.batch import segment_rows
    from ompn_ros.detect.online import BoundaryEvent
    from ompn_ros.segmenter import ReplayResult

    ep = synthetic.make_dataset("discrete", 1, seed=3)[0]
    T = ep.length
    empty = ReplayResult(
        p_hat=np.zeros((T, 4)),
        pi=np.zeros((T, 3)),
        pi_end=np.zeros(T),
        expected_position=np.zeros(T),
        scores=np.zeros(T),
    )
    stamps = np.arange(T + 1, dtype=np.int64) * 1000
    rows = segment_rows(0, ep, empty, stamps, "rising_edge")
    assert [(r["start_step"], r["end_step"], r["end_stamp_ns"], r["subtask"]) for r in rows] == [
        (0, T - 1, (T - 1) * 1000, 0)
    ]
    early = BoundaryEvent(step=T - 3, detected_at=T - 3, subtask=1, score=0.5, level=2, stamp_ns=0)
    first = BoundaryEvent(step=2, detected_at=3, subtask=0, score=0.5, level=2, stamp_ns=0)
    rows = segment_rows(0, ep, ReplayResult(**{**empty.__dict__, "boundaries": [first, early]}), stamps, "x")
    assert [(r["start_step"], r["end_step"]) for r in rows] == [(0, 2), (3, T - 1)]
    with open(tmp_path / "t.csv", "w", newline="") as fh:  # the table's columns take these rows
        csv.DictWriter(fh, fieldnames=list(rows[0])).writerows(rows)
