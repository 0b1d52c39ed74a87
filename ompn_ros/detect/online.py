"""Causal (online) subtask-boundary detectors fed one score per step.

The score is the code-weighted expected expansion position of the authors' evaluation
(``docs/craft.md`` §5.3, ``docs/dial.md`` §4.5 step 2), computed from the *unnormalised* ``p_hat`` ordered
``[pi_end, slot n (top), ..., slot 1 (bottom)]`` with weights ``w = [n, n-1, ..., 0] / n``::

    score_t = sum_k w_k * p_hat_t[k]   in [0, 1]

Offline, the paper standardises ``pi_avg`` by the trajectory's maximum before thresholding
(Algorithm 1).  That needs the whole trajectory, so online we use the fixed-range normalisation
``/ n`` instead: thresholds tuned offline therefore do not carry over one-to-one.

Detection follows the paper's Algorithm 1 ("the boundary is the last time step of a segment above
the threshold"), made causal:

* hysteresis: a run *starts* when ``score > high`` and *ends* when ``score <= low``
  (``low == high`` reproduces Algorithm 1 exactly);
* ``mode='falling_edge'`` (default, the paper's boundary): when a run ends at step ``t`` the
  boundary is ``t - 1``, the last in-run step, emitted at step ``t`` (commit lag 1 step);
* ``mode='peak'``: commit the first local maximum of the run (boundary ``t - 1`` as soon as
  ``score_t < score_{t-1}``); same lag, but long plateaus (Dial) commit before the run ends;
* ``mode='rising_edge'``: commit the first in-run step immediately (lag 0);
* a candidate that would make a segment shorter than ``min_segment_length`` steps is dropped;
* ``end_episode`` closes the episode with one event (docs/design.md#episode-end): the last segment's
  boundary at ``L - 1`` (Algorithm 1 appends it), or, when the end of the last subtask was published
  already, an *episode end* that reports no subtask: a boundary at or after ``L - 1``, a rising-edge or
  peak commit whose run lasts to the end (the expansion the episode ends in was counted once), or a
  tail shorter than ``min_segment_length`` after the last boundary;
* ``offset``: a committed boundary is reported that many steps earlier than its rule places it (never
  at or before the previous boundary), with that step's score, level and stamp; it is published at
  the same step as without the offset.  Calibrated on validation episodes when the score's runs end a
  steady few steps after the true boundaries (`ompn_segment --tune --long-subtasks`,
  docs/design.md#detector-grid).

``mode='hsmm'`` is a different decoder with the same step interface: the explicit-duration HSMM of
:mod:`ompn_ros.detect.duration`, which needs a duration model fitted on episodes; there ``high`` is
the posterior probability a boundary needs, and a boundary comes at least ``lag + 1`` steps after
its step (more when the evidence is weak).  ``mode='head'`` reads the model's whole output, not the
score: the learned boundary head of :mod:`ompn_ros.detect.head`; there ``high`` is the head's
probability a boundary needs at ``lag`` steps and ``min_segment_length`` the fewest steps between
two boundaries.  ``mode='head_hsmm'`` is the duration decoder with the head's probabilities as its
evidence instead of the score (:mod:`ompn_ros.detect.head_duration`); ``high`` and ``lag`` as for
'hsmm'.

Step 0 is forced to score 0 by default, as in the authors' evaluation (the first step's p_hat is
hard-coded to "expand from the top", ``docs/craft.md`` §3.6).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from ompn_ros.detect.errors import DetectorConfigError

MODES = ("falling_edge", "peak", "rising_edge")
"""The threshold detectors' commit rules (the grids of ``ompn_segment --tune`` and the calibration)."""
DURATION_MODE = "hsmm"
"""The mode of :class:`~ompn_ros.detect.duration.DurationDetector` (needs a fitted duration model)."""
HEAD_MODE = "head"
"""The mode of :class:`~ompn_ros.detect.head.HeadDetector` (needs a trained boundary head)."""
HEAD_DURATION_MODE = "head_hsmm"
"""The mode of :class:`~ompn_ros.detect.head_duration.HeadDurationDetector`: the duration decoder
weighing the boundary head's probabilities (needs both)."""
DURATION_MODES = (DURATION_MODE, HEAD_DURATION_MODE)
"""The modes of the duration decoder."""
ALL_MODES = (*MODES, DURATION_MODE, HEAD_MODE, HEAD_DURATION_MODE)
MAX_LAG = 10
"""The longest lag of the duration decoder (the fewest steps a boundary waits; see
:mod:`ompn_ros.detect.duration` for its cost per step)."""
MAX_OFFSET = 10
"""The largest ``offset`` of the threshold detectors (steps a boundary is moved back)."""
KEPT_STEPS = 4
"""Steps a threshold detector keeps of its episode (to close it at a marker's step a little behind
the stream), plus its ``offset``."""


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of :class:`OnlineDetector`.

    Attributes:
        high: a run starts when the score is strictly above ``high`` (in [0, 1]).
        low: a run ends when the score is at or below ``low``; ``None`` means ``low = high``
            (no hysteresis, the paper's Algorithm 1). Must satisfy ``0 <= low <= high``.
        min_segment_length: minimum number of steps of a segment closed by a detected boundary
            (``>= 1``; 1 disables the check).
        mode: 'falling_edge' | 'peak' | 'rising_edge', 'hsmm', 'head' or 'head_hsmm' (see the module
            docstring).
        force_first_step_low: treat step 0's score as 0 (the authors' evaluation does this).
        lag: the fewest steps the 'hsmm' and 'head_hsmm' decoders wait after a step is taken in before
            they publish it as a boundary, so at least ``lag + 1`` steps after the step (0 … ``MAX_LAG``; the
            threshold modes ignore it). Mode 'head': the lag the head's probability is read at
            (0 … the head's longest); the boundary is published ``lag + 1`` steps after its step.
        offset: the threshold modes report a boundary this many steps before the step their rule
            gives, never at or before the previous boundary (0 … ``MAX_OFFSET``; 'hsmm' needs 0).
            The boundary is still published when the rule commits it.
    """

    high: float = 0.5
    low: float | None = None
    min_segment_length: int = 1
    mode: str = "falling_edge"
    force_first_step_low: bool = True
    lag: int = 0
    offset: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.high, (int, float)) and 0.0 <= float(self.high) <= 1.0):
            raise DetectorConfigError(f"detector 'high' must be a number in [0, 1], got {self.high!r}")
        if self.low is not None:
            if not isinstance(self.low, (int, float)) or not 0.0 <= float(self.low) <= float(self.high):
                raise DetectorConfigError(
                    f"detector 'low' must be a number in [0, high={self.high}], got {self.low!r}"
                )
        if not isinstance(self.min_segment_length, (int, np.integer)) or self.min_segment_length < 1:
            raise DetectorConfigError(
                f"detector 'min_segment_length' must be an integer >= 1, got {self.min_segment_length!r}"
            )
        if self.mode not in ALL_MODES:
            raise DetectorConfigError(f"detector 'mode' must be one of {ALL_MODES}, got {self.mode!r}")
        lag = self.lag
        if isinstance(lag, bool) or not isinstance(lag, int | np.integer) or not 0 <= lag <= MAX_LAG:
            raise DetectorConfigError(f"detector 'lag' must be an integer in [0, {MAX_LAG}], got {lag!r}")
        offset = self.offset
        offset_int = isinstance(offset, int | np.integer) and not isinstance(offset, bool)
        if not offset_int or not 0 <= offset <= MAX_OFFSET:
            raise DetectorConfigError(
                f"detector 'offset' must be an integer in [0, {MAX_OFFSET}], got {offset!r}"
            )
        if self.mode not in MODES and offset:
            raise DetectorConfigError(
                f"detector 'offset' applies to the threshold modes {MODES}; mode '{self.mode}' needs 0, "
                f"got {offset}"
            )
        if self.mode not in MODES and not 0.0 < float(self.high) < 1.0:
            raise DetectorConfigError(
                f"detector 'high' of mode '{self.mode}' is a probability in (0, 1), got {self.high!r}"
            )

    @property
    def low_threshold(self) -> float:
        """The effective exit threshold."""
        return float(self.high if self.low is None else self.low)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> DetectorConfig:
        """Build from a mapping, rejecting unknown keys by name."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(values) - known)
        if unknown:
            raise DetectorConfigError(f"unknown detector parameter(s) {unknown}; known: {sorted(known)}")
        return cls(**values)


@dataclass(frozen=True)
class BoundaryEvent:
    """One detected subtask boundary.

    Attributes:
        step: index of the last step of the subtask that ended (the paper's boundary).
        detected_at: step index at which the event was emitted (``detected_at - step`` is the
            commit lag; 1 for the falling edge).
        subtask: 0-based ordinal within the episode of the subtask that ended.
        score: detector score at ``step``.
        level: hierarchy level at ``step``: the argmax of p_hat mapped to paper slot numbers
            (1 = bottom ... n = top, n + 1 = pi_end); 0 when unknown.
        stamp_ns: stamp of the observation of ``step`` (0 when unknown).
        final: True for the event that closes the episode (exactly one per episode that had a step, its
            last): the closing boundary, or the episode end.
        episode_end: True for an episode end that reports no subtask (``SubtaskBoundary.EPISODE_END``):
            the end of the episode's last subtask was published before.  ``step`` is then the episode's
            last step, ``subtask`` the number of subtasks the episode reported, ``score`` and ``level`` 0.
    """

    step: int
    detected_at: int
    subtask: int
    score: float
    level: int
    stamp_ns: int
    final: bool = False
    episode_end: bool = False


def subtask_ends(events: Sequence[BoundaryEvent]) -> list[BoundaryEvent]:
    """The events of ``events`` that report a subtask (one per subtask: every event but the episode end)."""
    return [event for event in events if not event.episode_end]


def expansion_score(p_hat: np.ndarray | Sequence[float]) -> float:
    """Code-weighted expected expansion position in [0, 1] from ``p_hat`` (``[n+1]``).

    ``sum_k w_k p_hat[k]`` with ``w = [n, ..., 0] / n`` (``docs/dial.md`` §4.5 step 2, divided by n).
    Plain float arithmetic: this runs once per streamed step on n + 1 (= 3 or 4) numbers.
    """
    p = p_hat.ravel().tolist() if isinstance(p_hat, np.ndarray) else list(p_hat)
    n = len(p) - 1
    if n < 1:
        raise ValueError(f"p_hat must have n+1 >= 2 entries, got {len(p)}")
    total = 0.0
    for k, value in enumerate(p):
        total += (n - k) * float(value)
    return min(max(total / n, 0.0), 1.0)


def expansion_scores(p_hat: np.ndarray) -> np.ndarray:
    """Vectorised :func:`expansion_score` over ``[T, n+1]`` (no step-0 override)."""
    p = np.asarray(p_hat, dtype=np.float64)
    n = p.shape[-1] - 1
    weights = np.arange(n, -1, -1, dtype=np.float64) / n
    return np.clip(p @ weights, 0.0, 1.0)


def expansion_level(p_hat: np.ndarray | Sequence[float]) -> int:
    """Argmax expansion level: paper slot number (1 = bottom, n = top), ``n + 1`` for pi_end."""
    p = p_hat.ravel().tolist() if isinstance(p_hat, np.ndarray) else list(p_hat)
    return len(p) - p.index(max(p))


@dataclass
class _StepRecord:
    score: float
    level: int
    stamp_ns: int


class EpisodeLog:
    """What every causal detector keeps of the current episode: the step counter, the last steps seen
    (to close at a marker's step), the boundaries published, and whether the episode is closed."""

    def _start(self, keep: int) -> None:
        self._step = -1
        self._recent: deque[tuple[int, _StepRecord]] = deque(maxlen=keep)
        self._last_boundary = -1
        self._n_boundaries = 0
        self._closed = False

    @property
    def closed(self) -> bool:
        """True after the episode was closed until :meth:`reset`."""
        return self._closed

    @property
    def steps_seen(self) -> int:
        return self._step + 1

    @property
    def boundaries_emitted(self) -> int:
        return self._n_boundaries

    @property
    def last_boundary(self) -> int:
        """Step index of the last emitted boundary (-1 before the first)."""
        return self._last_boundary

    def _next(self, score: float, level: int, stamp_ns: int, force_first_step_low: bool) -> _StepRecord:
        """Count the next step (its score 0 at step 0 when forced) and return its record (not kept yet)."""
        if self._closed:
            raise RuntimeError(f"{type(self).__name__}.update after the episode was closed; reset() first")
        self._step += 1
        low = self._step == 0 and force_first_step_low
        return _StepRecord(0.0 if low else float(score), int(level), int(stamp_ns))

    def _close_at(self, last_step: int | None) -> int | None:
        """Close the episode; the step that ends it: ``last_step`` (default the last seen), or the last
        step seen when ``last_step`` is too far back to be kept; None before any step."""
        self._closed = True
        if self._step < 0:
            return None
        end = self._step if last_step is None else min(int(last_step), self._step)
        if end < 0:
            return None
        return end if any(step == end for step, _ in self._recent) else self._recent[-1][0]

    def _record(self, step: int) -> _StepRecord:
        return next(r for s, r in self._recent if s == step)

    def _emit(self, step: int, detected_at: int, record: _StepRecord, final: bool = False) -> BoundaryEvent:
        event = BoundaryEvent(step=step, detected_at=detected_at, subtask=self._n_boundaries,
                              score=record.score, level=record.level, stamp_ns=record.stamp_ns, final=final)
        self._last_boundary = step
        self._n_boundaries += 1
        return event

    def _closing(self, end: int, decided: bool = False, min_length: int = 1) -> BoundaryEvent:
        """The event that closes the episode at step ``end`` (docs/design.md#episode-end): the final
        boundary of the last segment, or the episode end (no subtask) when the end of the last subtask
        was published already: a boundary at or after ``end``, ``decided`` (the detector's rule says
        the last boundary is the end the episode closes in), or fewer than ``min_length`` steps since
        the last boundary.  An episode without a boundary always closes with one."""
        tail = end - self._last_boundary
        if self._n_boundaries and (tail <= 0 or decided or tail < min_length):
            record = self._record(end)
            return BoundaryEvent(step=end, detected_at=self._step, subtask=self._n_boundaries, score=0.0,
                                 level=0, stamp_ns=record.stamp_ns, final=True, episode_end=True)
        return self._emit(end, self._step, self._record(end), final=True)


@dataclass
class OnlineDetector(EpisodeLog):
    """Causal boundary detector; feed it with :meth:`update` once per step."""

    config: DetectorConfig = field(default_factory=DetectorConfig)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Start a new episode."""
        self._start(keep=KEPT_STEPS + self.config.offset)
        self._in_run = False
        self._run_committed = False
        self._run_boundary = -1  # the boundary the current (or last) run committed; -1: none
        self._run_last = -1  # the last step of the last run that ended
        self._prev: _StepRecord | None = None

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the score of the next step; return the boundary committed at this step, if any."""
        cfg = self.config
        current = self._next(score, level, stamp_ns, cfg.force_first_step_low)
        t = self._step
        event: BoundaryEvent | None = None
        if not self._in_run:
            if current.score > cfg.high:
                self._in_run = True
                self._run_committed = False
                self._run_boundary = -1
                if cfg.mode == "rising_edge":
                    event = self._commit(t, current, t)
                    self._run_committed = True
        else:
            prev = self._prev
            assert prev is not None
            if current.score <= cfg.low_threshold:
                self._in_run = False
                self._run_last = t - 1
                if not self._run_committed:
                    event = self._commit(t - 1, prev, t)
            elif cfg.mode == "peak" and not self._run_committed and current.score < prev.score:
                event = self._commit(t - 1, prev, t)
                self._run_committed = True
        if event is not None:
            self._run_boundary = event.step
        self._prev = current
        self._recent.append((t, current))
        return event

    def configure(self, config: DetectorConfig) -> None:
        """Run ``config`` from the next step on (the episode so far is kept)."""
        self.config = config

    def close(self, last_step: int | None = None) -> list[BoundaryEvent]:
        """:meth:`end_episode` as the list every detector returns (the duration decoder may close with
        several boundaries)."""
        event = self.end_episode(last_step)
        return [] if event is None else [event]

    def end_episode(self, last_step: int | None = None) -> BoundaryEvent | None:
        """Close the episode at ``last_step`` (default: the last step seen) with its ``final`` event.

        That is the last segment's boundary at ``last_step``, or the episode end (no subtask) when the
        end of the last subtask was published already: a boundary at or after ``last_step`` (e.g. the
        falling edge at the done step), a rising-edge or peak commit whose run was still on at
        ``last_step``, or a tail shorter than ``min_segment_length``.  ``None`` when no step was seen.
        A ``last_step`` older than the last few steps kept (a marker that disagrees with the stream)
        closes at the last step seen, so the event always carries a real stamp. Call :meth:`reset`
        afterwards.
        """
        end = self._close_at(last_step)
        if end is None:
            return None
        run_open = self._in_run or self._run_last >= end
        decided = self._run_committed and run_open and 0 <= self._run_boundary == self._last_boundary
        return self._closing(end, decided, self.config.min_segment_length)

    def _commit(self, step: int, record: _StepRecord, detected_at: int) -> BoundaryEvent | None:
        if step - self._last_boundary < self.config.min_segment_length:
            return None
        moved = max(step - self.config.offset, self._last_boundary + 1)
        if moved != step:
            kept = [(s, r) for s, r in self._recent if s >= moved]
            if kept:  # a step older than those kept (offset raised inside the episode): the oldest kept
                step, record = kept[0]
        return self._emit(step, detected_at, record)


class StepDetector(Protocol):
    """A causal detector: :class:`OnlineDetector`, or the duration decoder
    (:mod:`ompn_ros.detect.duration`)."""

    def reset(self) -> None: ...

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None: ...

    def close(self, last_step: int | None = None) -> list[BoundaryEvent]: ...


def run_detector(
    detector: StepDetector,
    scores: np.ndarray,
    levels: np.ndarray | None = None,
    stamps_ns: np.ndarray | None = None,
    close_episode: bool = True,
) -> list[BoundaryEvent]:
    """Every event ``detector`` publishes over one episode's score sequence (reset first). O(T) updates."""
    detector.reset()
    events: list[BoundaryEvent] = []
    for t, score in enumerate(np.asarray(scores, dtype=np.float64)):
        level = int(levels[t]) if levels is not None else 0
        stamp = int(stamps_ns[t]) if stamps_ns is not None else 0
        event = detector.update(float(score), level, stamp)
        if event is not None:
            events.append(event)
    if close_episode:
        events.extend(detector.close())
    return events


def detect_sequence(
    scores: np.ndarray,
    config: DetectorConfig | None = None,
    levels: np.ndarray | None = None,
    stamps_ns: np.ndarray | None = None,
    close_episode: bool = True,
) -> list[BoundaryEvent]:
    """Run an :class:`OnlineDetector` over a whole score sequence (for tests and analysis)."""
    return run_detector(OnlineDetector(config or DetectorConfig()), scores, levels, stamps_ns, close_episode)
