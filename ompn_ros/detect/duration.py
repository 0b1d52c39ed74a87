"""A causal boundary decoder that knows how long subtasks last: an explicit-duration HSMM.

The threshold detectors of :mod:`ompn_ros.detect.online` look at one score at a time.  Their online
alignment lags the offline detectors because one early false alarm shifts every later segment
(docs/design.md#duration-decoder).  This decoder models an episode as ``K`` segments:

* segment ``i`` lasts ``L_i`` steps, ``L_i ~ P_i`` (one length distribution per segment index);
* the expansion score of step ``t`` (:func:`~ompn_ros.detect.online.expansion_score`, the paper's
  boundary signal, Lu et al., ICLR 2021, §3.3) comes from ``f1`` when ``t`` ends a segment and from
  ``f0`` otherwise (histograms over score bins).

That is an explicit-duration hidden semi-Markov model (Yu, "Hidden semi-Markov models", Artificial
Intelligence 174, 2010).  The decoder commits to one segmentation as it goes.  With ``j`` boundaries
published, the last at ``b``, it computes at every step ``t`` the posterior, given the scores
``s_{b+1..t}``, of where segment ``j`` ended (a step ``e`` in ``(b, t]``, or not yet)::

    P(end = e | s) ∝ P_j(e - b) · Π_{b<τ<e} f0(s_τ) · f1(s_e) · B_{j+1}(e + 1)

where ``B_i(a)`` is the likelihood of ``s_{a..t}`` when segment ``i`` starts at ``a`` (a backward
pass over the later segments, the last one still running at ``t``).  When the probability that
segment ``j`` ended at or before ``t - lag`` exceeds ``θ``, the most probable such end is published.
A step that was not published when it was ``lag`` steps old can still be published later, when later
scores make it likely (docs/design.md#duration-decoder); ``θ`` trades that delay for alignment.  At most one
boundary is published per step and at most ``K - 1`` inner ones per episode.  The episode end
closes the last segment: the remaining segments get their most probable ends (a Viterbi pass).

The decoder takes step ``t`` in when step ``t + 1`` arrives (or the episode is closed), so a boundary
is published at least ``lag + 1`` steps after its step.  An episode's last observation, the 'done'
step after the last action (its score is high: the memory expands from the top), is then dropped by
the episode end instead of being read as the end of a subtask, and the node publishes the
boundaries a replay of the episode's steps gives (docs/design.md#duration-decoder).

Cost per step: O(K · n²) for the ``n`` steps since the last published boundary (at most
:data:`MAX_SPAN`, a compiled kernel; a boundary is never placed further back); the episode end
O(K · n²) once; memory: those ``n`` steps and the ``K × (MAX_SPAN + 2)`` length tables.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from ompn_ros.detect.errors import DurationModelError
from ompn_ros.detect.online import (
    DURATION_MODE,
    MAX_LAG,
    BoundaryEvent,
    DetectorConfig,
    EpisodeLog,
    _StepRecord,
    run_detector,
    subtask_ends,
)

SCORE_BINS = 100
"""Histogram bins of the score over [0, 1]."""
MAX_DURATION = 60
"""Segment lengths above this share the hazard of this length."""
MAX_SPAN = 64
"""The most recent steps the decoder weighs (>= MAX_DURATION): a boundary is never placed further
back, and the current segment's steps before them only count towards its length."""
_NEG = -1.0e300


@dataclass(frozen=True, eq=False)
class DurationModel:
    """The fitted HSMM: ``K`` segments, their hazards and the score histograms.

    Attributes:
        subtasks: ``K``, the number of segments of an episode (the most common count when fitted).
        hazard: ``[K, max_duration + 1]``, ``hazard[i, u] = P(L_i = u | L_i >= u)`` in (0, 1)
            (column 0 unused).
        f0: ``[bins]`` probabilities of a score bin at a step that ends no segment.
        f1: ``[bins]`` probabilities of a score bin at a step that ends a segment.
        episodes: how many episodes it was fitted on.
    """

    subtasks: int
    hazard: np.ndarray
    f0: np.ndarray
    f1: np.ndarray
    episodes: int = 0
    logs: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    """log hazard, log(1 - hazard), log f1, log f0."""
    lengths: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)
    """``[K, MAX_SPAN + 2]`` log P(L_i = u) and log P(L_i >= u) (what the decoder reads)."""

    def __post_init__(self) -> None:
        hazard = np.asarray(self.hazard, dtype=np.float64)
        f0, f1 = (np.asarray(f, dtype=np.float64) for f in (self.f0, self.f1))
        if not isinstance(self.subtasks, int | np.integer) or self.subtasks < 1:
            raise DurationModelError(f"duration model 'subtasks' must be an int >= 1, got {self.subtasks!r}")
        if hazard.ndim != 2 or hazard.shape[0] != self.subtasks or hazard.shape[1] < 2:
            raise DurationModelError(
                f"duration model 'hazard' must have shape [subtasks={self.subtasks}, max_duration + 1], "
                f"got {hazard.shape}"
            )
        if not np.all((hazard[:, 1:] > 0.0) & (hazard[:, 1:] < 1.0)):
            raise DurationModelError("duration model 'hazard' must lie strictly between 0 and 1")
        for name, f in (("f0", f0), ("f1", f1)):
            if f.ndim != 1 or f.size < 2 or not np.all(f > 0.0) or abs(float(f.sum()) - 1.0) > 1e-6:
                raise DurationModelError(
                    f"duration model '{name}' must be positive probabilities summing to 1"
                )
        if f0.size != f1.size:
            raise DurationModelError(f"duration model 'f0' and 'f1' differ in length ({f0.size}, {f1.size})")
        object.__setattr__(self, "hazard", hazard)
        object.__setattr__(self, "f0", f0)
        object.__setattr__(self, "f1", f1)
        with np.errstate(divide="ignore"):  # column 0 (length 0) is unused
            logs = (np.log(hazard), np.log1p(-hazard), np.log(f1), np.log(f0))
        object.__setattr__(self, "logs", logs)
        object.__setattr__(self, "lengths", _length_tables(logs[0], logs[1]))

    def __eq__(self, other: object) -> bool:  # the arrays compared by value (rounded as stored)
        return isinstance(other, DurationModel) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash((self.subtasks, self.episodes, self.hazard.shape, self.f0.size))

    @property
    def bins(self) -> int:
        return int(self.f0.size)

    @property
    def boundary_share(self) -> float:
        """The share of steps that end an inner segment, ``(K - 1) / Σ_i E[L_i]`` (lengths up to the
        tables' end): the prior of a boundary at a step."""
        log_p = self.lengths[0]
        expected = float((np.exp(log_p) * np.arange(log_p.shape[1])).sum())
        return (self.subtasks - 1) / max(expected, 1.0)

    def bin_of(self, score: float) -> int:
        """The histogram bin of ``score`` (scores outside [0, 1] fall in the end bins)."""
        return min(max(int(score * self.bins), 0), self.bins - 1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "subtasks": int(self.subtasks),
            "episodes": int(self.episodes),
            "hazard": np.round(self.hazard, 8).tolist(),
            "f0": np.round(self.f0, 10).tolist(),
            "f1": np.round(self.f1, 10).tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any) -> DurationModel:
        """Parse :meth:`to_dict`'s layout."""
        if not isinstance(data, dict) or set(data) != {"subtasks", "episodes", "hazard", "f0", "f1"}:
            raise DurationModelError("duration model must be {'subtasks', 'episodes', 'hazard', 'f0', 'f1'}")
        try:
            f0, f1 = (np.asarray(data[k], dtype=np.float64) for k in ("f0", "f1"))
            hazard = np.asarray(data["hazard"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise DurationModelError(f"duration model arrays are not numeric: {exc}") from exc
        return cls(subtasks=data["subtasks"], hazard=hazard, f0=f0, f1=f1, episodes=data["episodes"])


def _length_tables(log_h: np.ndarray, log_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """log P(L_i = u) and log P(L_i >= u) for u in 0 … MAX_SPAN + 1 from the hazards (u = 0: impossible)."""
    top = log_h.shape[1] - 1
    u = np.minimum(np.arange(MAX_SPAN + 2), top)
    survive = np.zeros((log_h.shape[0], MAX_SPAN + 2))
    survive[:, 2:] = np.cumsum(log_c[:, u[1:-1]], axis=1)  # u >= 2: the lengths 1 … u - 1 passed
    exact = survive + log_h[:, u]
    exact[:, 0] = survive[:, 0] = _NEG
    return exact, survive


# --- fitting ---------------------------------------------------------------------------------------
def _histogram(values: np.ndarray, bins: int, alpha: float) -> np.ndarray:
    idx = np.clip((np.asarray(values, dtype=np.float64) * bins).astype(np.int64), 0, bins - 1)
    counts = np.bincount(idx, minlength=bins).astype(np.float64) + alpha
    return counts / counts.sum()


def _hazard(lengths: np.ndarray, max_duration: int, bandwidth: float) -> np.ndarray:
    """Hazard of the kernel-smoothed length histogram (Gaussian kernel of ``bandwidth`` steps)."""
    counts = np.bincount(np.minimum(lengths, max_duration), minlength=max_duration + 1).astype(np.float64)
    if bandwidth > 0:
        offsets = np.arange(-5, 6)
        kernel = np.exp(-0.5 * (offsets / bandwidth) ** 2)
        counts = np.convolve(counts, kernel / kernel.sum(), mode="same")
    counts = counts + 1e-3  # every length stays possible
    counts[0] = 0.0
    p = counts / counts.sum()
    survive = np.cumsum(p[::-1])[::-1]  # P(L >= u)
    return np.clip(p / np.maximum(survive, 1e-12), 1e-6, 1.0 - 1e-6)


def fit_duration_model(
    scores: Sequence[np.ndarray],
    boundaries: Sequence[np.ndarray],
    *,
    bins: int = SCORE_BINS,
    max_duration: int = MAX_DURATION,
    bandwidth: float = 1.0,
    alpha: float = 1.0,
) -> DurationModel:
    """Fit :class:`DurationModel` on episodes' per-step ``scores`` (step 0 as the detector sees it) and
    their ``boundaries`` (sorted last steps of the segments, the episode's last step included, as
    :func:`~ompn_ros.data.episode.boundaries_from_labels` gives them).

    ``K`` is the most common number of segments (ties: the smaller); the lengths come from the
    episodes with ``K`` segments, the score histograms from all.  ``alpha``: add-alpha smoothing of
    the histograms.  O(total steps).
    """
    if len(scores) != len(boundaries) or not scores:
        raise DurationModelError(f"need as many boundary arrays as score arrays (>= 1), got "
                                 f"{len(scores)} and {len(boundaries)}")
    ends, others, counts = [], [], []
    for s, b in zip(scores, boundaries):
        s, b = np.asarray(s, dtype=np.float64), np.asarray(b, dtype=np.int64)
        if b.size == 0 or b[-1] != s.size - 1 or np.any(np.diff(b) <= 0) or b[0] < 0:
            raise DurationModelError(f"boundaries {b.tolist()} are not sorted segment ends of a "
                                     f"{s.size}-step episode ending at its last step")
        inner = np.zeros(s.size, dtype=bool)
        inner[b[:-1]] = True
        rest = ~inner
        rest[0] = rest[-1] = False  # step 0 is forced low; the last step ends the episode, not a segment
        ends.append(s[inner])
        others.append(s[rest])
        counts.append(b.size)
    k = int(np.bincount(counts).argmax())
    lengths = np.array([np.diff(np.r_[-1, b]) for b in boundaries if len(b) == k])  # [episodes, K]
    hazard = np.stack([_hazard(lengths[:, i], max_duration, bandwidth) for i in range(k)])
    return DurationModel(subtasks=k, hazard=hazard, f0=_histogram(np.concatenate(others), bins, alpha),
                         f1=_histogram(np.concatenate(ends), bins, alpha), episodes=len(scores))


# --- the span posterior and the closing path (compiled) -------------------------------------------
@njit(cache=True, inline="always")
def _add(a: float, b: float) -> float:  # pragma: no cover - compiled
    """log(exp(a) + exp(b)) without overflow."""
    if a < b:
        a, b = b, a
    if b <= _NEG:
        return a
    return a + math.log1p(math.exp(b - a))


@njit(cache=True, inline="always")
def _log_length(log_p, log_s, i, u, running):  # type: ignore[no-untyped-def]  # pragma: no cover
    """log P(L_i = u), or log P(L_i >= u) when ``running``, beyond the tables too (a constant hazard
    past MAX_DURATION)."""
    top = log_p.shape[1] - 1
    if u <= top:
        return log_s[i, u] if running else log_p[i, u]
    survive = log_s[i, top] + (u - top) * (log_s[i, top] - log_s[i, top - 1])
    return survive if running else survive + log_p[i, top] - log_s[i, top]


@njit(cache=True)
def _end_posterior(log_p, log_s, log_f1, log_f0, bins, j, u0, first, last):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(P(segment ``j`` ended at a span index in [first, last] | the span's scores), its most probable
    end there, -1 for none).

    ``bins``: the score bins of the span; segment ``j`` had lasted ``u0`` steps before index 0;
    ``log_p[i, u]`` / ``log_s[i, u]``: log P(L_i = u) / log P(L_i >= u).  Segment K - 1 never ends
    inside the span."""
    k, n = log_p.shape[0], bins.shape[0]
    f = np.zeros(n + 1)  # f[a]: log f0 summed over indices < a
    for i in range(n):
        f[i + 1] = f[i] + log_f0[bins[i]]
    back = np.full((k, n + 1), _NEG)  # back[i, a]: log P(scores a..n-1 | segment i starts at a)
    for i in range(k):
        back[i, n] = 0.0
    for i in range(k - 1, j, -1):
        for a in range(n - 1, 0, -1):
            total = log_s[i, n - a + 1] + f[n] - f[a]
            if i < k - 1:
                for e in range(a, n):
                    v = log_p[i, e - a + 1] + f[e] - f[a] + log_f1[bins[e]] + back[i + 1, e + 1]
                    total = _add(total, v)
            back[i, a] = total
    total = _log_length(log_p, log_s, j, u0 + n + 1, True) + f[n]  # segment j still running
    ended, best, best_v = _NEG, -1, _NEG
    for e in range(first, n):
        v = _log_length(log_p, log_s, j, u0 + e + 1, False) + f[e] + log_f1[bins[e]] + back[j + 1, e + 1]
        total = _add(total, v)
        if e <= last:
            ended = _add(ended, v)
            if v > best_v:
                best, best_v = e, v
    return math.exp(ended - total), best


@njit(cache=True)
def _closing_path(log_p, log_s, log_f1, log_f0, bins, j, u0, first):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The most probable ends (span indices, the last = the span's last index) of segments j, j + 1, …
    when the span's last step ends the episode: K - j segments, fewer when the span is too short
    (segment ``j`` had lasted ``u0`` steps before index 0)."""
    k, n = log_p.shape[0], bins.shape[0]
    segs = min(k - j, n - first)
    if segs <= 1:
        return np.array([n - 1], dtype=np.int64)
    f = np.zeros(n + 1)
    for i in range(n):
        f[i + 1] = f[i] + log_f0[bins[i]]
    best = np.full((segs, n), _NEG)  # best[s, e]: segments j..j+s, segment j+s ends at index e
    prev = np.zeros((segs, n), dtype=np.int64)
    for e in range(first, n):
        here = log_f1[bins[e]] if e < n - 1 else 0.0
        best[0, e] = _log_length(log_p, log_s, j, u0 + e + 1, False) + f[e] + here
    for s in range(1, segs):
        for e in range(first + s, n):
            here = log_f1[bins[e]] if e < n - 1 else 0.0
            for q in range(first + s - 1, e):
                v = best[s - 1, q] + log_p[j + s, e - q] + f[e] - f[q + 1] + here
                if v > best[s, e]:
                    best[s, e], prev[s, e] = v, q
    path = np.empty(segs, dtype=np.int64)
    e = n - 1
    for s in range(segs - 1, -1, -1):
        path[s] = e
        e = prev[s, e]
    return path


# --- the decoder -----------------------------------------------------------------------------------
class DurationDetector(EpisodeLog):
    """The HSMM decoder; the step interface of :class:`~ompn_ros.detect.online.OnlineDetector`.

    Args:
        model: the fitted :class:`DurationModel`.
        lag: the fewest steps a boundary waits after its step is taken in (0 … :data:`MAX_LAG`); it is
            published at least ``lag + 1`` steps after its step.
        threshold: posterior probability ``θ`` in (0, 1) that the current segment has ended.
        force_first_step_low: treat step 0's score as 0, as the threshold detectors do.
    """

    mode = DURATION_MODE

    def __init__(self, model: DurationModel, lag: int = 0, threshold: float = 0.5,
                 force_first_step_low: bool = True) -> None:
        if isinstance(lag, bool) or not isinstance(lag, int | np.integer) or not 0 <= lag <= MAX_LAG:
            raise DurationModelError(f"lag must be an int in [0, {MAX_LAG}], got {lag!r}")
        if not isinstance(threshold, int | float) or not 0.0 < threshold < 1.0:
            raise DurationModelError(f"threshold must be a probability in (0, 1), got {threshold!r}")
        self.model, self.lag = model, int(lag)
        self.threshold, self.force_first_step_low = float(threshold), bool(force_first_step_low)
        self.reset()

    def configure(self, config: DetectorConfig) -> None:
        """Take ``config``'s threshold (``high``) from the next step; its lag must be this decoder's."""
        if config.mode != self.mode or config.lag != self.lag:
            raise DurationModelError(f"a running duration decoder (mode {self.mode}, lag {self.lag}) cannot "
                                     f"become {config}")
        self.threshold, self.force_first_step_low = float(config.high), bool(config.force_first_step_low)

    def reset(self) -> None:
        """Start a new episode."""
        self._start(keep=MAX_SPAN + 2)
        self._span: list[int] = []  # score bins of the decided steps since the last published boundary
        self._held: tuple[int, _StepRecord] | None = None  # the newest step, decided when the next comes

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the next step's score and decide on the step before it; the boundary published at
        this step (at least ``lag + 1`` steps back), if any.

        The newest step is held until the next one arrives (or the episode is closed): an episode's
        last observation, the 'done' step after the last action, then never enters the decoder, which
        sees exactly the steps the episode's segments cover, live as in a replay."""
        record = self._next(score, level, stamp_ns, self.force_first_step_low)
        self._recent.append((self._step, record))
        held, self._held = self._held, (self._step, record)
        return None if held is None else self._decide(*held)

    def _decide(self, step: int, record: _StepRecord) -> BoundaryEvent | None:
        """Add ``step`` to the span and publish the most probable end of the current segment, at least
        ``lag`` steps before ``step``, once its posterior exceeds the threshold."""
        self._span.append(self.model.bin_of(record.score))
        if len(self._span) > MAX_SPAN:
            del self._span[0]
        if self._n_boundaries >= self.model.subtasks - 1:
            return None
        start = step - len(self._span) + 1
        first, last = (1 if start == 0 else 0), len(self._span) - 1 - self.lag
        if last < first:
            return None
        log_p, log_s = self.model.lengths
        prob, end = _end_posterior(log_p, log_s, *self._evidence(start, len(self._span)), self._n_boundaries,
                                   start - self._last_boundary - 1, first, last)
        if prob <= self.threshold or end < 0:
            return None
        del self._span[: end + 1]
        return self._emit(start + end, self._step, self._record(start + end))

    def _evidence(self, start: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(log f1 table, log f0 table, each step's index into them) of the ``n`` span steps from step
        ``start``: here the score histograms and the steps' bins."""
        return self.model.logs[2], self.model.logs[3], np.asarray(self._span[:n], dtype=np.int64)

    def close(self, last_step: int | None = None) -> list[BoundaryEvent]:
        """Close the episode at ``last_step`` (default: the last step seen): the held step is decided
        when it lies within the episode (dropped when it is the 'done' step after ``last_step``), then
        the segments still open get their most probable ends, the last at ``last_step`` (the episode
        end, no subtask, when a boundary already ends at or after it: docs/design.md#episode-end).
        Call :meth:`reset` afterwards."""
        end = self._close_at(last_step)
        held, self._held = self._held, None
        events = []
        if end is not None and held is not None and held[0] <= end:
            event = self._decide(*held)
            events += [] if event is None else [event]
        if end is None:
            return events
        if end <= self._last_boundary:
            return [*events, self._closing(end)]
        decided = self._step if held is None or held[0] <= end else held[0] - 1
        start = decided - len(self._span) + 1
        if end >= start and self._n_boundaries < self.model.subtasks - 1:
            path = _closing_path(*self.model.lengths, *self._evidence(start, end - start + 1),
                                 self._n_boundaries, start - self._last_boundary - 1, 1 if start == 0 else 0)
            events += [self._emit(start + int(i), end, self._record(start + int(i))) for i in path[:-1]]
        events.append(self._closing(end))
        return events


def decode_episode(model: DurationModel, scores: np.ndarray, lag: int, threshold: float) -> np.ndarray:
    """The boundaries :class:`DurationDetector` publishes over a whole score sequence (the last step
    included), for calibration and tests.  O(T · K · n²), n <= MAX_SPAN the steps since the
    last published boundary."""
    events = run_detector(DurationDetector(model, lag, threshold), scores)
    return np.asarray([e.step for e in subtask_ends(events)], dtype=np.int64)


__all__ = ["DurationDetector", "DurationModel", "decode_episode", "fit_duration_model"]
