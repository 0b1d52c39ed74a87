"""``ompn_node`` runs a checkpoint's boundary head (detector modes 'head' and 'head_hsmm'): live equals
replay on a human-like stream, ``ompn_segment``'s scoring equals the streamed boundaries, and the
modes are refused live for a checkpoint without a head."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rclpy")

from human_streams import Recorder, _episodes, live, received  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from toy_heads import checkpoint_with_head  # noqa: E402

from ompn_ros.detect.duration import fit_duration_model  # noqa: E402
from ompn_ros.detect.grid import scores_from_p_hats  # noqa: E402
from ompn_ros.detect.head import HeadDetector, decode_rows  # noqa: E402
from ompn_ros.detect.head_duration import HeadDurationDetector, decode_head_duration  # noqa: E402
from ompn_ros.detect.online import DetectorConfig, subtask_ends  # noqa: E402
from ompn_ros.detect.settings import load_detector_settings, save_detector_settings  # noqa: E402
from ompn_ros.model.checkpoint import load_checkpoint  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402
from ompn_ros.train.evaluation import teacher_forced_p_hat  # noqa: E402
from sim_nodes.registry import expert_episode  # noqa: E402

torch.set_num_threads(1)


def checkpoint_with_both(tmp_path: Path, domain: str) -> Path:
    """:func:`checkpoint_with_head` running mode 'head_hsmm' with a duration model fitted on expert
    episodes."""
    path = checkpoint_with_head(tmp_path, domain)
    eps = [expert_episode(domain, 700 + i) for i in range(16)]
    p_hats = teacher_forced_p_hat(load_checkpoint(path)[0], eps)[0]  # type: ignore[arg-type]
    model = fit_duration_model(scores_from_p_hats(p_hats), [ep.boundaries for ep in eps])
    stored = load_detector_settings(path)
    both = DetectorConfig(mode="head_hsmm", high=0.9, lag=1)
    save_detector_settings(path, type(stored)(online=both, head=stored.head, duration_model=model,
                                              provenance="a test"))
    return path


@pytest.mark.parametrize(("domain", "mode"), [("craft", "head"), ("dial", "head"), ("craft", "head_hsmm"),
                                              ("dial", "head_hsmm")])
def test_the_head_runs_live_as_it_replays_on_a_human_like_stream(ctx, tmp_path: Path, domain: str,
                                                                 mode: str) -> None:
    made = checkpoint_with_head if mode == "head" else checkpoint_with_both
    path = made(tmp_path, domain)
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("checkpoint", value=str(path))])
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node.outputs.pubs = {k: Recorder() for k in node.outputs.pubs}
    seg = node.segmenter
    assert seg is not None and seg.head is not None
    assert isinstance(seg.detector, HeadDetector if mode == "head" else HeadDurationDetector)
    assert node.get_parameter("detector_mode").value == mode
    offline = StreamingSegmenter(seg.policy, seg.detector_config, seg.duration_model, seg.head)
    t0 = (int(time.time()) - 10_000) * 1_000_000_000
    inner = 0
    for i, ep in enumerate(_episodes(domain)):
        stream = received(ep)
        got, _ = live(node, stream, t0 + i * 10 * 1_000_000_000)
        replay = replay_episode(offline, stream, include_done_step=True)
        want = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.published]
        assert got == want, (i, got, want)
        end = replay.published[-1].detected_at  # the episode end decides its last steps
        lag = seg.detector_config.lag
        if mode == "head":
            assert all(b.detected_at in (b.step + lag + 1, end) for b in replay.boundaries)
        assert all(b.detected_at >= b.step + lag + 1 or b.detected_at == end for b in replay.boundaries)
        inner += len(replay.boundaries) - 1
        # ompn_segment's scoring decodes the replay's outputs at once, with the same rule
        assert replay.outputs is not None
        rows = seg.head.probabilities(replay.outputs)
        batch = (decode_rows(rows, seg.detector_config, seg.head.peak) if mode == "head"
                 else decode_head_duration(seg.duration_model, rows, seg.detector_config))  # type: ignore[arg-type]
        assert [b.step for b in subtask_ends(batch)] == [b.step for b in replay.boundaries]
        assert batch[-1].final and [b.episode_end for b in batch] == [b.episode_end for b in replay.published]
    assert inner > 3
    if mode == "head":
        result = node.set_parameters([Parameter("detector_lag", value=seg.head.max_lag + 1)])[0]
        assert not result.successful and "beyond this boundary head's lags" in result.reason
    node.destroy_node()


@pytest.mark.parametrize("mode", ["head", "head_hsmm"])
def test_the_head_modes_are_refused_for_a_checkpoint_without_a_head(ctx, mode: str, tmp_path: Path) -> None:
    import dataclasses
    import shutil

    from ompn_ros.checkpoints import shipped_checkpoint

    plain = Path(shutil.copytree(shipped_checkpoint("craft"), tmp_path / "craft"))
    settings = load_detector_settings(plain)
    (plain / "boundary_head.safetensors").unlink(missing_ok=True)
    save_detector_settings(plain, dataclasses.replace(settings, head=None))
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("checkpoint", value=str(plain))])
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.last_error
    both = [Parameter("detector_mode", value=mode), Parameter("detector_lag", value=2)]
    result = node.set_parameters(both)[0]
    assert not result.successful and f"'{mode}' needs a boundary head" in result.reason
    assert node.segmenter is not None and node.segmenter.detector_config.mode not in ("head", "head_hsmm")
    node.destroy_node()
