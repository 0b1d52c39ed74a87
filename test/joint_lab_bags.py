"""Another lab's bag: namespaced JointState, gripper and wrench topics, for the assembly tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import Writer

from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import storage_plugin

MS = 1_000_000


C = m.msg_class


JOINTS = ["j1", "j2", "j3"]


IDS = (17, 4, 9)


SPEC_DICT: dict[str, Any] = {
    "namespace": "/lab",
    "assemble": {
        "step_topic": "arm/joint_states",
        "tolerance_s": 0.03,
        "stamp": "receive",
        "fields": [
            {"topic": "arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "position"},
            {"topic": "arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "velocity"},
            {"topic": "arm/gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 2},
            {"topic": "arm/ft", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"},
        ],
    },
    "action": {"topic": "arm/command", "type": "std_msgs/msg/Float64MultiArray", "dim": 3},
    "subtask": "task/skill", "labels": "id", "sketch": None, "episode": None,
    "split": "gaps", "time_gap": 0.5, "tolerance": 0.03, "task": "lab_demo",
}


def f64(values: np.ndarray) -> bytes:
    dim = C("std_msgs/msg/MultiArrayDimension")(label="effort", size=len(values), stride=len(values))
    lay = C("std_msgs/msg/MultiArrayLayout")(dim=[dim], data_offset=0)
    return m.serialize(C("std_msgs/msg/Float64MultiArray")(layout=lay, data=np.asarray(values, float)))


def wrench(stamp: int, values: np.ndarray) -> bytes:
    v3 = C("geometry_msgs/msg/Vector3")
    w = C("geometry_msgs/msg/Wrench")(force=v3(*values[:3]), torque=v3(*values[3:]))
    return m.serialize(C("geometry_msgs/msg/WrenchStamped")(header=m.header(stamp, "ft"), wrench=w))


Message = tuple[int, str, bytes]


def _episode_messages(ep: int, t0: int, rng: np.random.Generator, truth: dict) -> list[Message]:
    n = 20 + 5 * ep
    out: list[Message] = []
    ids = np.repeat(IDS, [n // 3, n // 3, n - 2 * (n // 3)])
    for k in range(n):
        t = t0 + k * 40 * MS
        pos, vel = rng.standard_normal(3), rng.standard_normal(3)
        grip, ft = rng.random(2), rng.standard_normal(6)
        if ep == 1 and k == 7:
            truth["stale"] += 1  # no gripper message: the one of step 6 is 45 ms old (> 30 ms)
        elif ep == 2 and k == 5:
            out.append((t - 5 * MS, "/lab/arm/gripper", m.encode_float32_array(np.ones(3), "grip")))
            truth["wrong_size"] += 1
        else:
            out.append((t - 5 * MS, "/lab/arm/gripper", m.encode_float32_array(grip, "grip")))
        out.append((t - 2 * MS, "/lab/arm/ft", wrench(t - 2 * MS, ft)))
        out.append((t, "/lab/arm/joint_states", m.serialize(m.joint_state(t, JOINTS, pos, vel))))
        truth["obs"].append(np.concatenate([pos, vel, grip, ft]).astype(np.float32))
        if k < n - 1:  # the last joint state of an episode is its final observation
            out.append((t + 5 * MS, "/lab/task/skill", m.serialize(m.int32(int(ids[k])))))
            act = rng.standard_normal(3)
            out.append((t + 10 * MS, "/lab/arm/command", f64(act)))
            truth["act"].append(act.astype(np.float32))
            truth["ids"].append(int(ids[k]))
    return out


TYPES = {
    "/lab/arm/gripper": "std_msgs/msg/Float32MultiArray", "/lab/arm/ft": "geometry_msgs/msg/WrenchStamped",
    "/lab/arm/joint_states": "sensor_msgs/msg/JointState", "/lab/task/skill": "std_msgs/msg/Int32",
    "/lab/arm/command": "std_msgs/msg/Float64MultiArray",
}


def write_lab_bag(path: Path, seed: int = 0) -> dict:
    """Three episodes 2 s apart; one stale and one wrong-size gripper; truth per step."""
    rng = np.random.default_rng(seed)
    truth: dict = {"obs": [], "act": [], "ids": [], "stale": 0, "wrong_size": 0}
    messages: list[tuple[int, str, bytes]] = []
    for ep in range(3):
        messages += _episode_messages(ep, 10**10 + ep * 4 * 10**9, rng, truth)
    with Writer(path, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {t: w.add_connection(t, ty, typestore=m.typestore()) for t, ty in TYPES.items()}
        for stamp, topic, raw in sorted(messages, key=lambda x: x[0]):
            w.write(conns[topic], stamp, raw)
    return truth
