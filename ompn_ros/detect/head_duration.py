"""The duration decoder over the boundary head: mode 'head_hsmm'
(docs/design.md#duration-decoder-over-the-head).

The duration decoder (:mod:`ompn_ros.detect.duration`) weighs one number per step, the expansion
score, through two histograms, and its length model keeps it from extra and missing boundaries.  The
boundary head (:mod:`ompn_ros.detect.head`) reads the model's whole output and places boundaries
more precisely, but knows nothing of lengths.  This decoder is the first with the second's evidence:
when it decides step ``t``, the evidence that step ``τ`` ended a segment is the head's probability
``p`` for ``τ`` at lag ``min(t - τ, max_lag)``, the newest row that has seen it, as a scaled likelihood
(a network's posterior divided by its prior, Bourlard and Morgan, "Connectionist Speech Recognition",
1994)::

    log f1(τ) = log p - log π,    log f0(τ) = log(1 - p) - log(1 - π)

``π`` is the duration model's share of boundary steps (:attr:`DurationModel.boundary_share`).  The
rest is the duration decoder's: ``high`` is the posterior a boundary needs, a boundary comes at least
``lag + 1`` steps after its step, the episode end closes the open segments, and the newest step is
held until the next one arrives, so an episode's 'done' observation never places one.

Cost per step: the head's forward pass plus the duration decoder's O(K · n²).  Memory: the duration
decoder's plus the head's rows of the last ``MAX_SPAN + max_lag`` steps.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ompn_ros.detect.duration import MAX_SPAN, DurationDetector, DurationModel
from ompn_ros.detect.errors import BoundaryHeadError
from ompn_ros.detect.head import BoundaryHead, FedByHead
from ompn_ros.detect.online import HEAD_DURATION_MODE, BoundaryEvent, DetectorConfig

_EDGE = 1e-6
"""Probabilities are clipped to [_EDGE, 1 - _EDGE] before their logarithms."""


class HeadDurationDecoder(DurationDetector):
    """The decoder over rows of head probabilities: :meth:`take` one row ``[max_lag + 1]`` per step.

    Args:
        model: the fitted :class:`DurationModel` (its lengths; the score histograms are not read).
        max_lag: the head's longest lag.
        lag, threshold, force_first_step_low: as for :class:`DurationDetector`.
    """

    mode = HEAD_DURATION_MODE

    def __init__(self, model: DurationModel, max_lag: int, lag: int = 0, threshold: float = 0.5,
                 force_first_step_low: bool = True) -> None:
        if isinstance(max_lag, bool) or not isinstance(max_lag, int) or max_lag < 0:
            raise BoundaryHeadError(f"max_lag must be an int >= 0, got {max_lag!r}")
        self.max_lag = max_lag
        prior = model.boundary_share
        self._log_prior = (float(np.log(prior)), float(np.log1p(-prior)))
        super().__init__(model, lag, threshold, force_first_step_low)

    def reset(self) -> None:
        super().reset()
        self._rows = np.zeros((MAX_SPAN + self.max_lag + 2, self.max_lag + 1))  # step s at s % len
        self._newest_row = -1  # the step of the newest row

    def take(self, row: np.ndarray, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the next step's probabilities (and its score, for the event's record); the boundary
        published now, if any."""
        if row.shape != (self.max_lag + 1,):
            raise BoundaryHeadError(f"a head row has {self.max_lag + 1} lags, got {row.shape}")
        event = DurationDetector.update(self, score, level, stamp_ns)
        self._newest_row += 1
        self._rows[self._newest_row % len(self._rows)] = row
        return event

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        raise BoundaryHeadError(f"mode '{self.mode}' reads the head's rows: use take()")

    def _evidence(self, start: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-step log f1 and log f0 of the span steps ``start … start + n - 1`` from the newest row
        that has seen each (rows of steps after the span's last are not read)."""
        newest = start + n - 1
        taus = np.arange(start, newest + 1)
        lags = np.minimum(newest - taus, self.max_lag)
        p = np.clip(self._rows[(taus + lags) % len(self._rows), lags], _EDGE, 1.0 - _EDGE)
        log_prior, log_rest = self._log_prior
        return np.log(p) - log_prior, np.log1p(-p) - log_rest, np.arange(n, dtype=np.int64)


class HeadDurationDetector(FedByHead, HeadDurationDecoder):
    """Mode 'head_hsmm' as a streaming detector: :meth:`feed` the step's outputs, then :meth:`update`."""

    def __init__(self, model: DurationModel, head: BoundaryHead, config: DetectorConfig) -> None:
        if config.mode != HEAD_DURATION_MODE:
            raise BoundaryHeadError(f"HeadDurationDetector runs mode '{HEAD_DURATION_MODE}', got "
                                    f"{config.mode!r}")
        self._attach(head)
        HeadDurationDecoder.__init__(self, model, head.max_lag, config.lag, config.high,
                                     config.force_first_step_low)


def decode_head_duration(model: DurationModel, rows: np.ndarray, config: DetectorConfig,
                         scores: Sequence[float] | np.ndarray | None = None) -> list[BoundaryEvent]:
    """Every boundary :class:`HeadDurationDecoder` publishes over one episode's head rows
    ``[T, max_lag + 1]`` (``scores``: the steps' scores for the events, 0 when not given)."""
    decoder = HeadDurationDecoder(model, rows.shape[1] - 1, config.lag, config.high,
                                  config.force_first_step_low)
    values = np.zeros(len(rows)) if scores is None else np.asarray(scores, dtype=np.float64)
    taken = (decoder.take(r, float(s)) for r, s in zip(rows, values, strict=True))
    events = [e for e in taken if e is not None]
    return events + decoder.close()


__all__ = ["HeadDurationDecoder", "HeadDurationDetector", "decode_head_duration"]
