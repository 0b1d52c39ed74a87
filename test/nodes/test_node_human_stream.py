"""Live equals replay on a human-like stream: ``ompn_node`` (in process, the shipped Craft or Dial
checkpoint and its own detector) fed what ``craft_sim`` / ``dial_sim demonstrator:=human`` publishes
(pauses, detours, variable speed, sensor noise, a dropped observation never arrives, a duplicated one
arrives twice) publishes exactly the boundaries and ``~/pi`` of an offline replay of the same received
stream."""

from __future__ import annotations

import time

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from human_streams import Recorder, _episodes, live, received  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from ompn_ros.data.episode import observation_copies  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402

torch.set_num_threads(1)


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_live_output_on_a_human_like_stream_equals_its_replay(ctx, domain: str) -> None:
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("domain", value=domain)])
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node.outputs.pubs = {k: Recorder() for k in node.outputs.pubs}
    seg = node.segmenter
    assert seg is not None
    offline = StreamingSegmenter(seg.policy, seg.detector_config, seg.duration_model, seg.head)
    t0 = (int(time.time()) - 10_000) * 1_000_000_000
    n_events = copies_seen = 0
    for i, ep in enumerate(_episodes(domain)):
        copies_seen += int((observation_copies(ep) != 1).sum())
        stream = received(ep)
        got, pis = live(node, stream, t0 + i * 10 * 1_000_000_000)
        replay = replay_episode(offline, stream, include_done_step=True)
        want = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.published]
        assert got == want, (i, got, want)
        inner = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.boundaries]
        assert want[:len(inner) - 1] == inner[:-1]  # the published boundaries of the T real steps
        # one event per subtask, then the episode end when no subtask ended with the episode
        assert [b.subtask for b in replay.published] == list(range(len(replay.published)))
        assert [b.final for b in replay.published] == [False] * (len(replay.published) - 1) + [True]
        assert len(pis) == len(stream.observations)
        np.testing.assert_allclose(pis[:-1, -1], replay.pi_end, atol=1e-6)
        np.testing.assert_allclose(pis[:-1, -2], replay.expected_position, atol=1e-5)
        n_events += len(got)
    assert copies_seen > 0 and n_events > 6  # drops/duplicates happened; inner boundaries were found
    node.destroy_node()
