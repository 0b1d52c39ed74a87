"""StreamingSegmenter input validation: rejected input never touches the memory."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from ompn_ros.data.episode import Episode
from ompn_ros.detect.duration import DurationDetector, fit_duration_model
from ompn_ros.detect.errors import DurationModelError
from ompn_ros.detect.online import DetectorConfig, OnlineDetector
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.stream.replay import replay_episode
from ompn_ros.validate import (
    EmptyObservation,
    EpisodeClosed,
    InvalidInput,
    MissingSketch,
    NonFiniteObservation,
    OutOfOrderStamp,
    SketchError,
    WrongObservationLength,
)


@dataclass
class FakeConfig:
    obs_dim: int = 4
    n_slots: int = 3
    action_type: str = "discrete"
    action_dim: int = 5
    sketch_mode: str = "none"
    sketch_vocab: int = 0


@dataclass
class FakeStep:
    action: int
    pi: np.ndarray
    pi_end: float
    p_hat: np.ndarray
    expected_position: float
    done_prob: float
    action_logits: np.ndarray | None = None


class FakePolicy:
    """A recurrent stand-in: the memory is a decaying sum of observations, p_hat a softmax of it."""

    def __init__(self, config: FakeConfig | None = None) -> None:
        self.config = config or FakeConfig()
        rng = np.random.default_rng(1)
        self.w = rng.normal(size=(self.config.obs_dim, self.config.n_slots + 1))
        self.memory = np.zeros(self.config.obs_dim)
        self.steps = 0

    def reset(self, sketch: np.ndarray | None = None) -> None:
        self.memory = np.zeros(self.config.obs_dim)
        if sketch is not None:
            self.memory[: len(sketch)] += sketch[: self.config.obs_dim]
        self.steps = 0

    def step(self, obs: np.ndarray) -> FakeStep:
        assert obs.dtype == np.float32 and obs.shape == (self.config.obs_dim,)
        self.memory = 0.5 * self.memory + obs
        self.steps += 1
        z = self.memory @ self.w
        p_hat = np.exp(z - z.max())
        p_hat /= p_hat.sum()
        pi = p_hat[1:][::-1] / p_hat[1:].sum()
        pos = float(np.arange(1, len(pi) + 1) @ pi)
        logits = z.astype(np.float32)
        return FakeStep(int(np.argmax(z)), pi, float(p_hat[0]), p_hat, pos, float(p_hat[0]), logits)


def make_segmenter(**cfg: object) -> StreamingSegmenter:
    return StreamingSegmenter(FakePolicy(FakeConfig(**cfg)), DetectorConfig(high=0.5))  # type: ignore[arg-type]


BAD_INPUTS = [
    ([], None, EmptyObservation, "empty"),
    (np.zeros(3), None, WrongObservationLength, "wrong_length"),
    (np.zeros(5), None, WrongObservationLength, "wrong_length"),
    ([0.0, np.nan, 0.0, 0.0], None, NonFiniteObservation, "non_finite"),
    ([0.0, 0.0, np.inf, 0.0], None, NonFiniteObservation, "non_finite"),
    (np.array([np.inf, 0.0, -np.inf, 0.0], np.float32), None, NonFiniteObservation, "non_finite"),
    (np.array([0.0, 0.0, 0.0, np.nan], np.float32), None, NonFiniteObservation, "non_finite"),
    (["a", "b", "c", "d"], None, NonFiniteObservation, "non_finite"),
    (np.ones(4), 5, OutOfOrderStamp, "out_of_order_stamp"),
    (np.ones(4), 10, OutOfOrderStamp, "out_of_order_stamp"),  # equal stamp = duplicate
]


@pytest.mark.parametrize("obs, stamp, error, reason", BAD_INPUTS)
def test_bad_input_raises_named_error_and_leaves_memory_untouched(obs, stamp, error, reason) -> None:
    rng = np.random.default_rng(2)
    stream = rng.normal(size=(6, 4)).astype(np.float32)
    clean, dirty = make_segmenter(), make_segmenter()
    ref = [clean.step(x, stamp_ns=10 * (i + 1)) for i, x in enumerate(stream)]
    for i, x in enumerate(stream):
        if i == 1:
            memory_before = dirty.policy.memory.copy()
            with pytest.raises(error) as info:
                dirty.step(obs, stamp_ns=stamp, after_ns=10)  # the previous step's stamp
            assert isinstance(info.value, InvalidInput) and info.value.reason == reason
            np.testing.assert_array_equal(dirty.policy.memory, memory_before)
            assert dirty.step_index == 0
        out = dirty.step(x, stamp_ns=10 * (i + 1))
        np.testing.assert_array_equal(out.step_output.p_hat, ref[i].step_output.p_hat)
        assert out.step_index == ref[i].step_index == i
        assert out.boundary == ref[i].boundary
    assert dirty.rejected[reason] == 1 and dirty.rejected_total == 1
    assert dirty.accepted == clean.accepted == 6


def test_contiguous_float32_input_is_used_as_is_and_other_input_converted() -> None:
    seg = make_segmenter()
    stepped: list[np.ndarray] = []

    def held(arr: np.ndarray, stamp: int) -> bool:  # what step() hands on, seen through its hold
        stepped.append(arr)
        return False

    def validated(obs: object) -> np.ndarray:
        assert seg.step(obs, hold=held) is None
        return stepped[-1]

    flat = np.arange(4, dtype=np.float32)
    assert validated(flat) is flat  # the node's parsed messages: no copy, no conversion
    column = np.arange(8, dtype=np.float64).reshape(4, 2)[:, 0]  # strided float64
    out = validated(column)
    assert out.dtype == np.float32 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, [0, 2, 4, 6])
    np.testing.assert_array_equal(validated([[1, 2], [3, 4]]), [1, 2, 3, 4])
    assert seg.step_index == -1 and seg.accepted == 0  # held: no step


def test_error_messages_name_the_problem() -> None:
    seg = make_segmenter()
    with pytest.raises(WrongObservationLength, match=r"3 values.*obs_dim=4"):
        seg.step(np.zeros(3))
    with pytest.raises(NonFiniteObservation, match="index 1"):
        seg.step([0.0, np.nan, 0.0, 0.0])
    seg.step(np.zeros(4), stamp_ns=100)
    with pytest.raises(OutOfOrderStamp, match=r"99 ns.*100 ns"):
        seg.step(np.zeros(4), stamp_ns=99, after_ns=100)


def test_stamps_checked_against_the_stamp_the_caller_names() -> None:
    seg = make_segmenter()  # the segmenter keeps no stamp: the stream rule owns the episode's last one
    seg.step(np.zeros(4), stamp_ns=100)
    with pytest.raises(OutOfOrderStamp):
        seg.step(np.zeros(4), stamp_ns=50, after_ns=100)
    assert seg.step(np.zeros(4), stamp_ns=50).step_index == 1
    # unstamped steps are always accepted
    assert seg.step(np.zeros(4), after_ns=100).step_index == 2


def test_sketch_is_validated_against_the_model() -> None:
    seg = make_segmenter(sketch_mode="sum", sketch_vocab=5)
    assert not seg.ready
    with pytest.raises(MissingSketch):
        seg.step(np.zeros(4))
    assert seg.rejected["no_sketch"] == 1
    with pytest.raises(SketchError, match="needs a sketch"):
        seg.reset(None)
    with pytest.raises(SketchError, match="vocabulary"):
        seg.reset(np.array([1, 7]))
    with pytest.raises(SketchError, match="integer"):
        seg.reset(np.array([1.5]))
    seg.reset(np.array([1, 2]))
    np.testing.assert_array_equal(seg.sketch, [1, 2])
    # a model without sketch ignores a published sketch
    plain = make_segmenter()
    plain.reset(np.array([3, 4]))
    assert plain.sketch is None


def test_reset_restarts_step_index_and_detector() -> None:
    seg = make_segmenter()
    x = np.ones(4, dtype=np.float32)
    first = [seg.step(x).step_output.p_hat for _ in range(3)]
    assert [e.final for e in seg.end_episode()] == [True]
    with pytest.raises(EpisodeClosed):
        seg.step(x)
    assert seg.rejected["episode_closed"] == 1
    seg.reset()
    again = [seg.step(x).step_output.p_hat for _ in range(3)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    assert seg.step_index == 2 and seg.episodes == 2


def test_replay_episode_excludes_done_step_and_closes_at_t_minus_1() -> None:
    rng = np.random.default_rng(3)
    T = 12
    ep = Episode(
        observations=rng.normal(size=(T + 1, 4)).astype(np.float32),
        actions=np.zeros(T, dtype=np.int64),
        subtask=np.repeat(np.arange(3), 4),
    )
    seg = make_segmenter()
    with_done = replay_episode(seg, ep, include_done_step=True)
    without = replay_episode(seg, ep)
    assert with_done.p_hat.shape == without.p_hat.shape == (T, 4)
    np.testing.assert_array_equal(with_done.p_hat, without.p_hat)
    assert with_done.boundary_steps[-1] == without.boundary_steps[-1] == T - 1
    assert all(b.step <= T - 1 for b in with_done.boundaries)
    assert with_done.scores[0] == pytest.approx(with_done.scores[0])
    assert np.all(np.diff(without.boundary_steps) > 0)


def test_a_decoder_change_inside_an_episode_applies_from_the_next_one() -> None:
    rng = np.random.default_rng(0)
    bounds = [np.cumsum(rng.integers(4, 7, size=3)) - 1 for _ in range(40)]
    model = fit_duration_model([np.where(np.isin(np.arange(b[-1] + 1), b), 0.8, 0.1) for b in bounds], bounds)
    seg = StreamingSegmenter(FakePolicy(FakeConfig()), DetectorConfig(high=0.5), model)  # type: ignore[arg-type]
    x = np.ones(4, dtype=np.float32)
    seg.step(x)
    assert seg.set_detector(DetectorConfig(high=0.4)) == "from the next step"  # same decoder
    assert seg.detector.config.high == 0.4  # type: ignore[union-attr]
    hsmm = DetectorConfig(mode="hsmm", high=0.5, lag=2)
    assert seg.set_detector(hsmm) == "from the next episode"
    assert isinstance(seg.detector, OnlineDetector)  # the episode keeps its decoder
    assert seg.set_detector(DetectorConfig(mode="hsmm", high=0.7, lag=2)) == "from the next episode"
    assert seg.detector.config.high == 0.4  # type: ignore[union-attr]  # not given the hsmm threshold
    seg.end_episode()
    seg.reset()
    assert isinstance(seg.detector, DurationDetector)
    assert (seg.detector.lag, seg.detector.threshold) == (2, 0.7)
    with pytest.raises(DurationModelError, match="needs a duration model"):
        StreamingSegmenter(FakePolicy(FakeConfig()), hsmm)  # type: ignore[arg-type]
