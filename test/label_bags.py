"""Bags labelled the way another lab labels them (skill ids, ordinals, boundary events)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer

from ompn_ros import layout
from ompn_ros.data import ReaderSpec
from ompn_ros.data import messages as m

OBS_DIM, ACT_DIM = 6, 2
STEP = 50_000_000  # 20 Hz


SKILL_IDS = [[17, 17, 4, 4, 4, 9, 9], [4, 4, 9, 9, 4, 4], [9, 9, 9, 2, 2, 4, 4, 4]]


def _ordinals(ids: list[int]) -> list[int]:
    out, k = [], 0
    for t, v in enumerate(ids):
        k += t > 0 and v != ids[t - 1]
        out.append(k)
    return out


def _write_lab_bag(path: Path, labels: str, *, final_obs: bool = True, reset_topic: bool = False,
                   pause_ns: int = 2_000_000_000) -> list[dict]:
    """Episodes of SKILL_IDS under /lab7; ``labels`` = what /lab7/skill holds (or 'boundary':
    /lab7/skill_done events).  Each step: features, command, label; pauses separate episodes."""
    rng = np.random.default_rng(12)
    ts = m.typestore()
    truth, t = [], 3_000_000_000
    with Writer(path, version=9) as w:
        obs_c = w.add_connection("/lab7/cam/features", layout.FLOAT32_ARRAY, typestore=ts)
        act_c = w.add_connection("/lab7/arm/cmd", layout.FLOAT32_ARRAY, typestore=ts)
        if labels == "boundary":
            lab_c = w.add_connection("/lab7/skill_done", layout.STRING, typestore=ts)
        else:
            lab_c = w.add_connection("/lab7/skill", layout.INT32, typestore=ts)
        reset_c = w.add_connection("/lab7/reset", layout.STRING, typestore=ts) if reset_topic else None
        for ids in SKILL_IDS:
            n = len(ids)
            obs = rng.standard_normal((n + 1, OBS_DIM)).astype(np.float32)
            act = rng.standard_normal((n, ACT_DIM)).astype(np.float32)
            if reset_c is not None:
                w.write(reset_c, t - 1_000_000, m.serialize(m.msg_class(layout.STRING)(data="reset")))
            for k in range(n + 1 if final_obs else n):
                base = t + k * STEP
                w.write(obs_c, base, m.serialize(m.float32_array(obs[k], "features")))
                if k == n:
                    break
                w.write(act_c, base + 1_000_000, m.serialize(m.float32_array(act[k], "cmd")))
                _write_label(w, lab_c, labels, ids, k, base + 2_000_000)
            truth.append({"obs": obs if final_obs else obs[:n], "act": act, "ids": ids})
            t += (n + 1) * STEP + pause_ns
    return truth


def _write_label(w: Writer, conn: object, labels: str, ids: list[int], k: int, stamp: int) -> None:
    if labels == "id":
        w.write(conn, stamp, m.encode_int32(ids[k]))
    elif labels == "ordinal":
        w.write(conn, stamp, m.encode_int32(_ordinals(ids)[k]))
    elif labels == "boundary" and (k == len(ids) - 1 or ids[k + 1] != ids[k]):
        w.write(conn, stamp, m.serialize(m.msg_class(layout.STRING)(data="done")))


def _spec(labels: str, **extra: object) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "namespace": "/lab7",
        "observation": {"topic": "cam/features", "dim": OBS_DIM},
        "action": {"topic": "arm/cmd", "type": layout.FLOAT32_ARRAY, "dim": ACT_DIM},
        "subtask": "skill_done" if labels == "boundary" else "skill",
        "sketch": None, "episode": None, "labels": labels, "time_gap": 1.0, "strict": True,
        **extra,
    })
