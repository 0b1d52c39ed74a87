"""Bags of another lab (JointState + skill ids, rosbags' writer) for the batch, shard and cache tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ompn_ros import layout
from ompn_ros.data import messages as m

SPEC = {"reader": {
    "namespace": "/lab", "observation": {"topic": "features", "type": layout.FLOAT32_ARRAY},
    "action": {"topic": "cmd", "type": layout.FLOAT32_ARRAY, "dim": 2}, "subtask": "skill", "labels": "id",
    "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5, "tolerance": 0.03, "stamp": "log",
    "task": "lab_demo", "final_observation": "duplicate"}}


def write_lab_bag(path: Path, seed: int, episodes: int = 2, steps: int = 30) -> list[list[int]]:
    """Another lab's recording (rosbags writer): features, commands and skill ids at 20 Hz, episodes
    split by 2 s pauses; returns the observation log stamps of each episode."""
    from rosbags.rosbag2 import Writer

    rng = np.random.default_rng(seed)
    t, stamps = 1_700_000_000_000_000_000 + seed * 10**12, []
    with Writer(path, version=9) as w:
        ts = m.typestore()
        obs = w.add_connection("/lab/features", layout.FLOAT32_ARRAY, typestore=ts)
        cmd = w.add_connection("/lab/cmd", layout.FLOAT32_ARRAY, typestore=ts)
        skill = w.add_connection("/lab/skill", layout.INT32, typestore=ts)
        for _ in range(episodes):
            ids = np.repeat(rng.choice([3, 7, 11], size=3, replace=False), steps // 3)
            stamps.append([])
            for k in range(steps):
                w.write(obs, t, m.serialize(m.float32_array(rng.standard_normal(4))))
                w.write(cmd, t + 5_000_000, m.serialize(m.float32_array(rng.standard_normal(2), "cmd")))
                w.write(skill, t + 6_000_000, m.serialize(m.int32(int(ids[k]))))
                stamps[-1].append(t)
                t += 50_000_000
            t += 2_000_000_000
    return stamps
