"""``ompn_node``'s ``episode_gap``: episodes split by pauses, live, with the bag reader's rule.

The rule alone (against the reader's ``windows_from_gaps``), the silence watch, and the node in-process:
a stream of two episodes separated by a pause is segmented as two fresh replays, and a silence ends
the open episode from the timer without waiting for the next step."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from random_checkpoint import random_checkpoint

from ompn_ros.data.cuts import SilenceWatch, gap_ends_episode
from ompn_ros.data.reader.align import windows_from_gaps

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from node_in_process import active_node as poison_active_node  # noqa: E402 (publishers that record)
from rclpy.parameter import Parameter  # noqa: E402

from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.ros.params import ParameterError  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

OBS_DIM = 6
S = 1_000_000_000
torch.set_num_threads(1)


def test_the_rule_cuts_where_the_reader_cuts() -> None:
    rng = np.random.default_rng(0)
    steps = rng.choice([40_000_000, 40_000_000, 40_000_000, 500_000_000, 500_000_001, 1_300_000_000], 400)
    stamps = np.cumsum(steps).astype(np.int64)
    gap_ns = round(0.5 * S)
    cuts = [i for i in range(1, stamps.size) if gap_ends_episode(int(stamps[i]), int(stamps[i - 1]), gap_ns)]
    reader = [w.first_obs for w in windows_from_gaps(0.5, stamps)][1:]
    assert cuts == reader and len(cuts) > 10
    assert not gap_ends_episode(10 * S, None, gap_ns)  # the first step of an episode
    assert not gap_ends_episode(10 * S, 0, 0)  # off


def test_silence_watch_fires_after_the_gap_without_a_new_step() -> None:
    watch = SilenceWatch(S)
    assert not watch.quiet(0, 5, True)  # first look: remembers the count
    assert not watch.quiet(S // 2, 5, True)
    assert not watch.quiet(S // 2 + 1, 6, True)  # a new step restarts the wait
    assert not watch.quiet(S + S // 2, 6, True)
    assert watch.quiet(S + S // 2 + 1, 6, True)
    assert not watch.quiet(5 * S, 6, False)  # a closed episode never fires
    watch.rearm()
    assert not watch.quiet(6 * S, 6, True) and not watch.quiet(2 * S, 6, True)  # clock went back: wait again
    assert not watch.quiet(2 * S + S - 1, 6, True) and watch.quiet(3 * S, 6, True)
    with pytest.raises(ValueError, match="gap"):
        SilenceWatch(0)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "gap", seed=3,
                             obs_dim=OBS_DIM, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)


class FakeClock:
    def __init__(self) -> None:
        self.ns = 0

    def now(self) -> Any:
        return type("Now", (), {"nanoseconds": self.ns})()


def active_node(ctx, ckpt: Path, **params: Any) -> OMPNNode:
    """An active node whose publishers record (``test_node_poison``), stamps never checked against
    its clock (``max_stamp_lead`` 0: the tests' stamps are not wall time)."""
    return poison_active_node(ctx, ckpt, max_stamp_lead=0.0, **params)


def events(node: OMPNNode) -> list[tuple[int, str, int, str]]:
    out = []
    for raw in node.outputs.pubs["boundary"].raws:
        b = decode_subtask_boundary(raw)
        out.append((b.step, f"{b.score:.6f}", b.stamp_ns, str(b.final).lower()))
    return out


def replay(ckpt: Path, obs: np.ndarray, stamps: list[int]) -> list[tuple[int, str, int, str]]:
    """A fresh replay of one episode closed at its last step (what the node knows without a marker)."""
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig(high=0.3, low=0.3))
    seg.reset(None)
    out = []
    for x, s in zip(obs, stamps, strict=True):
        event = seg.step(x, s).boundary
        if event is not None:
            out.append(event)
    out = out + seg.end_episode(len(obs) - 1)
    return [(e.step, f"{float(np.float32(e.score)):.6f}", e.stamp_ns, str(e.final).lower()) for e in out]


def test_a_pause_between_stamps_ends_the_episode_like_a_marker(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, episode_gap=0.5)
    rng = np.random.default_rng(1)
    first, second = rng.normal(size=(14, OBS_DIM)), rng.normal(size=(9, OBS_DIM))
    t1 = [100 * S + 40_000_000 * t for t in range(len(first))]
    t2 = [t1[-1] + S + 40_000_000 * t for t in range(len(second))]  # 1 s pause, then the next episode
    for x, s in zip(np.concatenate([first, second]), t1 + t2, strict=True):
        node.inputs.on_raw_array(m.encode_float32_array(x.astype(np.float32)), s)
    got = events(node)
    want_first = replay(ckpt, first, t1)
    assert got[: len(want_first)] == want_first  # closed by the pause, at its last step, final
    assert want_first[-1][0] == len(first) - 1 and want_first[-1][3] == "true"
    # the second episode starts fresh: step indices from 0, memory reset
    assert [e for e in got[len(want_first):]] == [e for e in replay(ckpt, second, t2) if e[3] != "true"]
    counters = node.counters()
    assert (counters["episode_gaps"], counters["episodes"], counters["rejected"]) == (1, 2, 0)
    node.destroy_node()


def test_silence_ends_the_open_episode_from_the_timer(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, episode_gap=0.5)
    clock = FakeClock()
    node.get_clock = lambda: clock  # type: ignore[method-assign]
    rng = np.random.default_rng(2)
    obs = rng.normal(size=(7, OBS_DIM)).astype(np.float32)
    stamps = [50 * S + 40_000_000 * t for t in range(len(obs))]
    for x, s in zip(obs, stamps, strict=True):
        node.inputs.on_raw_array(m.encode_float32_array(x), s)
    before = len(node.outputs.pubs["boundary"].raws)
    for now in (0, S // 4, S // 2 - 1):  # quiet for just under half a second of the node's clock
        clock.ns = now
        node._check_silence()
    assert len(node.outputs.pubs["boundary"].raws) == before
    clock.ns = S // 2
    node._check_silence()
    assert events(node)[-1] == replay(ckpt, obs, stamps)[-1]  # the final boundary, at the last step
    assert node.counters()["episode_gaps"] == 1 and node.segmenter.step_index == -1
    clock.ns = 5 * S
    node._check_silence()  # nothing open: nothing more
    assert node.counters()["episode_gaps"] == 1
    node.destroy_node()


def test_without_episode_gap_a_pause_is_just_time(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    assert node._gap_timer is None
    for t, s in enumerate([S, 2 * S, 30 * S]):
        node.inputs.on_raw_array(m.encode_float32_array(np.full(OBS_DIM, t, np.float32)), s)
    assert node.counters()["episode_gaps"] == 0 and node.segmenter.step_index == 2
    node.destroy_node()


@pytest.mark.parametrize("bad", [-1.0, 0.001])
def test_episode_gap_is_validated(ctx, ckpt: Path, bad: float) -> None:
    with pytest.raises(ParameterError, match="episode_gap"):
        OMPNNode(context=ctx, parameter_overrides=[Parameter("checkpoint", value=str(ckpt)),
                                                   Parameter("episode_gap", value=bad)])


def test_the_node_splits_only_beyond_the_gap_like_the_reader(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, episode_gap=0.5)
    stamps = [10 * S, 10 * S + S // 2, 11 * S + 1]  # exactly the gap: same episode; 1 ns more: a new one
    for t, s in enumerate(stamps):
        node.inputs.on_raw_array(m.encode_float32_array(np.full(OBS_DIM, t, np.float32)), s)
    cuts = [i for i in range(1, len(stamps)) if gap_ends_episode(stamps[i], stamps[i - 1], S // 2)]
    assert cuts == [2] and node.counters()["episode_gaps"] == 1 and node.segmenter.step_index == 0
    node.destroy_node()
