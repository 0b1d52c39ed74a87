"""A causal boundary decoder that knows how long subtasks last: an explicit-duration HSMM with a fixed lag.

The threshold detectors of :mod:`ompn_ros.detect.online` look at one score at a time.  Their online
alignment lags the offline detectors because one early false alarm shifts every later segment
(docs/experiments.md §23, §34, §38).  This decoder models an episode as ``K`` segments:

* segment ``i`` lasts ``L_i`` steps, ``L_i ~ P_i`` (one length distribution per segment index);
* the expansion score of step ``t`` (:func:`~ompn_ros.detect.online.expansion_score`, the paper's
  boundary signal, Lu et al., ICLR 2021, §3.3) comes from ``f1`` when ``t`` ends a segment and from
  ``f0`` otherwise (histograms over score bins).

That is an explicit-duration hidden semi-Markov model (Yu, "Hidden semi-Markov models", Artificial
Intelligence 174, 2010).  The decoder commits to one segmentation as it goes: with ``j`` boundaries
published, the last at ``b``, the candidate ``c = t - lag`` is published at step ``t`` when the
posterior odds that ``c`` ends segment ``j``, given the scores up to ``t``, exceed ``θ / (1 - θ)``::

    odds(c) = h_j(c - b) f1(s_c) W(j + 1, 1) / ((1 - h_j(c - b)) f0(s_c) W(j, c - b + 1))

where ``h_j(u) = P(L_j = u | L_j >= u)`` is the hazard and ``W(i, u)`` the likelihood of the lag
window ``s_{c+1..t}`` starting in segment ``i`` at duration ``u``.  At most ``K - 1`` inner
boundaries are published; the episode end closes the last segment and decides the candidates still
inside the lag window, knowing the episode ended.

Cost per step: one candidate, two window likelihoods of O(K · lag²) (a compiled kernel); memory:
the last ``lag + 4`` steps and the ``K × (max_duration + 1)`` hazard table.  The published boundary
comes ``lag`` steps after its step (``detected_at - step = lag``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from ompn_ros.detect.online import (
    DURATION_MODE,
    MAX_LAG,
    BoundaryEvent,
    DetectorConfig,
    EpisodeLog,
    OnlineDetector,
    run_detector,
)

SCORE_BINS = 100
"""Histogram bins of the score over [0, 1]."""
MAX_DURATION = 60
"""Segment lengths above this share the hazard of this length."""
_NEG = -1.0e300


class DurationModelError(ValueError):
    """An invalid duration model, or episodes a model cannot be fitted on; the message says which."""


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
    """log hazard, log(1 - hazard), log f1, log f0 (what the decoder reads)."""

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

    def __eq__(self, other: object) -> bool:  # the arrays compared by value (rounded as stored)
        return isinstance(other, DurationModel) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash((self.subtasks, self.episodes, self.hazard.shape, self.f0.size))

    @property
    def bins(self) -> int:
        return int(self.f0.size)

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


# --- the window likelihood (compiled) --------------------------------------------------------------
@njit(cache=True, inline="always")
def _add(a: float, b: float) -> float:  # pragma: no cover - compiled
    """log(exp(a) + exp(b)) without overflow."""
    if a < b:
        a, b = b, a
    if b <= _NEG:
        return a
    return a + math.log1p(math.exp(b - a))


@njit(cache=True)
def _window(log_h, log_c, log_f1, log_f0, bins, j, u, final):  # type: ignore[no-untyped-def]  # pragma: no cover
    """log P(scores of ``bins`` | the first of them is step ``u`` of segment ``j``).

    Segment K - 1 never ends inside the window; with ``final`` the window's last step ends it."""
    k, top = log_h.shape[0], log_h.shape[1] - 1
    n = bins.shape[0]
    if n == 0:
        return 0.0
    stay = 0.0  # in segment j at duration u + i
    seg = np.full((k, n + 2), _NEG)  # seg[i, v]: in segment i > j at duration v
    for i in range(n):
        b = bins[i]
        nxt = np.full((k, n + 2), _NEG)
        uu = min(u + i, top)
        if final and i == n - 1:
            total = stay + log_h[j, uu] + log_f1[b] if j == k - 1 else _NEG
            for v in range(1, i + 1):
                total = _add(total, seg[k - 1, v] + log_h[k - 1, min(v, top)] + log_f1[b])
            return total
        if j < k - 1:
            nxt[j + 1, 1] = stay + log_h[j, uu] + log_f1[b]
            stay = stay + log_c[j, uu] + log_f0[b]
        else:
            stay = stay + log_f0[b]
        for seg_i in range(j + 1, k):
            for v in range(1, i + 1):
                a = seg[seg_i, v]
                if a <= _NEG:
                    continue
                vv = min(v, top)
                if seg_i < k - 1:
                    nxt[seg_i + 1, 1] = _add(nxt[seg_i + 1, 1], a + log_h[seg_i, vv] + log_f1[b])
                    nxt[seg_i, v + 1] = _add(nxt[seg_i, v + 1], a + log_c[seg_i, vv] + log_f0[b])
                else:
                    nxt[seg_i, v + 1] = _add(nxt[seg_i, v + 1], a + log_f0[b])
        seg = nxt
    total = stay
    for seg_i in range(j + 1, k):
        for v in range(1, n + 2):
            total = _add(total, seg[seg_i, v])
    return total


# --- the decoder -----------------------------------------------------------------------------------
class DurationDetector(EpisodeLog):
    """The fixed-lag HSMM decoder; the step interface of :class:`~ompn_ros.detect.online.OnlineDetector`.

    Args:
        model: the fitted :class:`DurationModel`.
        lag: steps a boundary waits before it is published (0 … :data:`MAX_LAG`).
        threshold: posterior probability ``θ`` in (0, 1) a boundary needs.
        force_first_step_low: treat step 0's score as 0, as the threshold detectors do.
    """

    def __init__(self, model: DurationModel, lag: int = 0, threshold: float = 0.5,
                 force_first_step_low: bool = True) -> None:
        if isinstance(lag, bool) or not isinstance(lag, int | np.integer) or not 0 <= lag <= MAX_LAG:
            raise DurationModelError(f"lag must be an int in [0, {MAX_LAG}], got {lag!r}")
        if not isinstance(threshold, int | float) or not 0.0 < threshold < 1.0:
            raise DurationModelError(f"threshold must be a probability in (0, 1), got {threshold!r}")
        self.model, self.lag = model, int(lag)
        self.threshold, self.force_first_step_low, self._log_odds = 0.5, True, 0.0
        self._set(threshold, force_first_step_low)
        self.reset()

    def _set(self, threshold: float, force_first_step_low: bool) -> None:
        self.threshold, self.force_first_step_low = float(threshold), bool(force_first_step_low)
        self._log_odds = math.log(self.threshold / (1.0 - self.threshold))

    def configure(self, config: DetectorConfig) -> None:
        """Take ``config``'s threshold (``high``) from the next step; its lag must be this decoder's."""
        if config.mode != DURATION_MODE or config.lag != self.lag:
            raise DurationModelError(f"a running duration decoder (lag {self.lag}) cannot become {config}")
        self._set(config.high, config.force_first_step_low)

    def reset(self) -> None:
        """Start a new episode."""
        self._start(keep=self.lag + 4)

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the next step's score; the boundary published at this step (``lag`` steps back), if any."""
        record = self._next(score, level, stamp_ns, self.force_first_step_low)
        self._recent.append((self._step, record))
        return self._decide(self._step - self.lag, self._step, final=False)

    def close(self, last_step: int | None = None) -> list[BoundaryEvent]:
        """Close the episode at ``last_step`` (default: the last step seen): the candidates still in the
        lag window are decided knowing the episode ends there, then the final boundary (none when a
        boundary already ends at or after it).  Call :meth:`reset` afterwards."""
        end = self._close_at(last_step)
        if end is None:
            return []
        events = []
        for c in range(max(1, self._step - self.lag + 1, self._last_boundary + 1), end):
            event = self._decide(c, end, final=True)
            if event is not None:
                events.append(event)
        if self._last_boundary < end:
            events.append(self._emit(end, self._step, self._record(end), final=True))
        return events

    def _decide(self, c: int, t: int, final: bool) -> BoundaryEvent | None:
        """Publish ``c`` as the end of the current segment when its posterior odds pass the threshold."""
        j, b = self._n_boundaries, self._last_boundary
        if c < 1 or c <= b or j >= self.model.subtasks - 1:
            return None
        log_h, log_c, log_f1, log_f0 = self.model.logs
        logs = (log_h, log_c, log_f1, log_f0)
        window = np.array([self.model.bin_of(r.score) for s, r in self._recent if c < s <= t], dtype=np.int64)
        u = min(c - b, log_h.shape[1] - 1)
        record = self._record(c)
        here = self.model.bin_of(record.score)
        ends = log_h[j, u] + log_f1[here] + _window(*logs, window, j + 1, 1, final)
        stays = log_c[j, u] + log_f0[here] + _window(*logs, window, j, c - b + 1, final)
        if ends - stays <= self._log_odds:
            return None
        return self._emit(c, t, record)


def decode_episode(model: DurationModel, scores: np.ndarray, lag: int, threshold: float) -> np.ndarray:
    """The boundaries :class:`DurationDetector` publishes over a whole score sequence (the last step
    included), for calibration and tests.  O(T · K · lag²)."""
    events = run_detector(DurationDetector(model, lag, threshold), scores)
    return np.asarray([e.step for e in events], dtype=np.int64)


Detector = OnlineDetector | DurationDetector
"""What :class:`~ompn_ros.segmenter.StreamingSegmenter` steps (``update``, ``close``, ``configure``,
``reset``)."""


def make_detector(config: DetectorConfig, model: DurationModel | None) -> Detector:
    """The detector of ``config``: the threshold detector, or for mode 'hsmm' the duration decoder of
    ``model`` (a :class:`DurationModelError` without one)."""
    if config.mode != DURATION_MODE:
        return OnlineDetector(config)
    if model is None:
        raise DurationModelError(
            f"detector mode '{DURATION_MODE}' needs a duration model: the checkpoint's detector.json has "
            "none (ompn_train writes one when it can fit it)"
        )
    return DurationDetector(model, config.lag, config.high, config.force_first_step_low)


__all__ = [
    "Detector", "DurationDetector", "DurationModel", "DurationModelError", "decode_episode",
    "fit_duration_model", "make_detector",
]
