"""``ompn_node`` runs a checkpoint's boundary head (detector mode 'head'): live equals replay on a
human-like stream, ``ompn_segment``'s scoring equals the streamed boundaries, and the mode is refused
live for a checkpoint without a head."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rclpy")

from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from test_boundary_head import checkpoint_with_head  # noqa: E402
from test_node_human_stream import Recorder, _episodes, live, received  # noqa: E402

from ompn_ros.detect.head import HeadDetector, decode_rows  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402

torch.set_num_threads(1)


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_the_head_runs_live_as_it_replays_on_a_human_like_stream(ctx, tmp_path: Path, domain: str) -> None:
    path = checkpoint_with_head(tmp_path, domain)
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("checkpoint", value=str(path))])
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node._pubs = {k: Recorder() for k in node._pubs}
    seg = node.segmenter
    assert seg is not None and isinstance(seg.detector, HeadDetector)
    assert node.get_parameter("detector_mode").value == "head"
    offline = StreamingSegmenter(seg.policy, seg.detector_config, seg.duration_model, seg.head)
    t0 = (int(time.time()) - 10_000) * 1_000_000_000
    inner = 0
    for i, ep in enumerate(_episodes(domain)):
        stream = received(ep)
        got, _ = live(node, stream, t0 + i * 10 * 1_000_000_000)
        replay = replay_episode(offline, stream, include_done_step=True)
        want = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.published]
        assert got == want, (i, got, want)
        end = replay.boundaries[-1].detected_at  # the episode end decides its last steps
        assert all(b.detected_at in (b.step + seg.detector_config.lag + 1, end) for b in replay.boundaries)
        inner += len(replay.boundaries) - 1
        # ompn_segment's scoring decodes the replay's outputs at once, with the same rule
        assert replay.outputs is not None
        batch = decode_rows(seg.head.probabilities(replay.outputs), seg.detector_config, seg.head.peak)
        assert [b.step for b in batch] == [b.step for b in replay.boundaries]
    assert inner > 3
    result = node.set_parameters([Parameter("detector_lag", value=seg.head.max_lag + 1)])[0]
    assert not result.successful and "beyond this boundary head's lags" in result.reason
    node.destroy_node()


def test_the_head_mode_is_refused_for_a_checkpoint_without_a_head(ctx) -> None:
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("domain", value="craft")])
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.last_error
    both = [Parameter("detector_mode", value="head"), Parameter("detector_lag", value=2)]
    result = node.set_parameters(both)[0]
    assert not result.successful and "needs a boundary head" in result.reason
    assert node.segmenter is not None and node.segmenter.detector_config.mode != "head"
    node.destroy_node()
