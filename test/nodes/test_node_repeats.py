"""ompn_node and a driver that publishes the same message twice: one step, as the bag reader reads it
once (docs/bags.md, ``ompn_ros.data.cuts.repeats``); counted ``repeated_messages``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from driver_streams import ARM, NOW_S, ckpts, events, msg  # noqa: E402, F401
from node_in_process import active_node  # noqa: E402

from ompn_ros.data import messages as m  # noqa: E402

S, MS = 1_000_000_000, 1_000_000
REPEATED = {3, 7, 8, 15}  # steps whose message goes out twice


def _run(node: Any, source: str, obs: np.ndarray, repeat: bool) -> None:
    for k, x in enumerate(obs):
        t = NOW_S * S + k * 40 * MS
        for copy in range(2 if repeat and k in REPEATED else 1):
            if source == "array":  # the copy: the same bytes, 2 µs later (source timestamp)
                node.inputs.on_raw_array(m.encode_float32_array(x, "obs"), t + copy * 2000)
            else:  # the copy: the same header stamp and data
                node.inputs.joint_states.on_joint_state(msg(t, ARM, x))


@pytest.mark.parametrize("source", ["array", "joint_state"])
def test_a_message_sent_twice_is_one_step(ctx, ckpts: dict[int, Path], source: str) -> None:  # noqa: F811
    """Was: every copy was a step (a repeated observation stepped twice, boundaries shifted)."""
    obs = np.random.default_rng(2).normal(size=(20, 3)).astype(np.float32)
    nodes = []
    for repeat in (False, True):
        node = active_node(ctx, ckpts[3], obs_source=source, max_stamp_lead=0.0)
        _run(node, source, obs, repeat)
        node.stream.close_episode(None)
        nodes.append(node)
    clean, repeated = nodes
    assert events(repeated) == events(clean) and events(clean)
    assert repeated.counters()["accepted"] == clean.counters()["accepted"] == 20
    assert repeated.counters()["repeated_messages"] == len(REPEATED)
    assert clean.counters()["repeated_messages"] == 0
    for node in nodes:
        node.destroy_node()
