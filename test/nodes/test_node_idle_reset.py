"""``idle_s`` live: an episode marker or ``~/reset`` ends the stream the idle rule sees, as the end of a
bag does for the reader's ``split: idle`` (docs/bags.md): the episode ends at its first held still
observation and the other held ones are trimmed; none of them is stepped into the next episode."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from driver_streams import ARM, ckpts, events, idle_bag, msg, replay, stream_pos  # noqa: E402, F401
from episode_markers import marker  # noqa: E402
from node_in_process import active_node  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ompn_ros import layout  # noqa: E402

HELD = 10  # still observations held when the marker or the reset comes (fewer than idle_s: 25)


def _interrupt(node: Any, how: str) -> None:
    if how == "reset":
        assert node._on_reset(Trigger.Request(), Trigger.Response()).success
    elif how == "end_marker":
        node.inputs.markers.on_episode(marker(layout.EPISODE_END))
    else:
        node.inputs.markers.on_episode(marker(layout.EPISODE_START))


@pytest.mark.parametrize("how", ["reset", "end_marker", "start_marker"])
def test_marker_or_reset_flushes_the_held_still_observations(
        ctx, ckpts: dict[int, Path], tmp_path: Path, how: str) -> None:  # noqa: F811 (the imported fixture)
    """Was: the held still observations stayed in the idle rule across the reset and the first of them
    was stepped into the new episode as its final observation (an extra episode, wrong boundaries)."""
    stream, offline = idle_bag(tmp_path, 1)
    first_end = 16 + 50 + HELD  # the first demonstration, then HELD of its 50 still observations
    node = active_node(ctx, ckpts[3], obs_source="joint_state", idle_s=0.5, idle_speed=0.01,
                       max_stamp_lead=0.0)
    for i, (head, pos, vel) in enumerate(stream):
        if i == first_end:
            _interrupt(node, how)
        node.inputs.joint_states.on_joint_state(msg(head, ARM, pos, vel))
    stamps, positions, want = np.asarray([h for h, _, _ in stream]), stream_pos(stream), []
    for e in offline.episodes:
        first = int(np.flatnonzero(np.all(positions == e.observations[0], axis=1))[0])
        want += replay(ckpts[3], e.observations, stamps[first + np.arange(len(e.observations))])
    assert len(offline.episodes) == 2 and events(node) == want
    counters = node.counters()
    assert counters["episodes"] == 2 and counters["episodes_ended"] == 2
    assert counters["idle_trimmed"] == offline.report.bags[0].idle_trimmed
    node.destroy_node()
