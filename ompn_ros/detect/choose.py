"""Which online and offline detector a checkpoint runs, and with which settings: the one place that
decides (docs/design.md#choosing-the-detector), for ``ompn_train`` (:func:`choose_settings`) and
``ompn_segment --tune`` (:func:`choose_on_replayed`).  Its defaults are :mod:`ompn_ros.detect.defaults`.

From validation episodes (their expansion distributions ``p_hat`` and online scores):

* with labels: the online threshold detector tuned on them (:func:`~ompn_ros.detect.calibrate.tune_on_labels`,
  the grid and objective of ``ompn_segment --tune``) and the offline detector the caller found best
  (``ompn_train``: the best validation alignment among Top-K, the automatic threshold and the
  constrained Top-K with its ``min_length`` tuned too);
* without labels: the online detector calibrated to agree with the model's own whole-episode
  segmentation (:func:`~ompn_ros.detect.calibrate.calibrate_label_free` against
  :data:`~ompn_ros.detect.defaults.LABEL_FREE_REFERENCE`), and the automatic threshold offline, the
  only offline detector that needs no number of subtasks.

The objective follows the domain's headline metric: boundary F1 for discrete actions (Craft),
alignment for continuous ones (Dial).

Both ways also fit the duration decoder (mode 'hsmm', :mod:`ompn_ros.detect.duration`) on the same
targets (the labels, or the pooled constrained Top-K without them) and tune its threshold for
alignment at the lag :data:`~ompn_ros.detect.defaults.DURATION_LAG`, with a mean delay of at most
:data:`~ompn_ros.detect.defaults.DURATION_DELAY` steps; the checkpoint keeps the model.  It becomes
the online detector when its validation alignment beats the threshold detector's by
:data:`~ompn_ros.detect.defaults.DURATION_GAIN` with F1@1 at most that much lower
(docs/design.md#duration-decoder).

With labels and a learned boundary head fitted (mode 'head', :mod:`ompn_ros.detect.head`; trained
by ``ompn_train``), the head's decoding becomes the online detector when its validation alignment is
higher than that of the detector chosen above (docs/design.md#boundary-head); with the duration
model fitted too, the duration decoder over the head (mode 'head_hsmm') has its threshold tuned the
same way, and becomes the online detector when its validation alignment is higher still
(docs/design.md#duration-decoder-over-the-head).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect.calibrate import Calibration, calibrate_label_free, tune_on_labels
from ompn_ros.detect.defaults import (
    DEFAULT_OBJECTIVE,
    DURATION_DELAY,
    DURATION_GAIN,
    DURATION_LAG,
    LABEL_FREE_MIN_LENGTH,
    LABEL_FREE_REFERENCE,
    LABEL_FREE_REFERENCE_MIN_LENGTH,
    Objective,
    objective_for,
)
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.duration_tuning import DurationCalibration, calibrate_duration, calibrate_head_duration
from ompn_ros.detect.errors import DurationModelError
from ompn_ros.detect.grid import evaluate_grid, scores_from_p_hats
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import DURATION_MODE, HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.detect.reference import pooled_counts, reference_boundaries
from ompn_ros.detect.settings import DetectorSettings, OfflineDetector, SettingsSource
from ompn_ros.detect.tune import Metrics, Replayed, choose_on_replays, default_grid, score_online

LOG = logging.getLogger("ompn_ros.train")


def calibrate_without_labels(
    p_hats: Sequence[np.ndarray],
    episodes: Sequence[Episode],
    action_type: str,
    scores: Sequence[np.ndarray] | None = None,
) -> Calibration:
    """The online detector ``ompn_train`` bundles without labels: calibrated on the validation
    ``p_hats`` against :data:`LABEL_FREE_REFERENCE` (counts pooled over the episodes' task names)."""
    return calibrate_label_free(
        p_hats, objective_for(action_type), LABEL_FREE_REFERENCE, min_length=LABEL_FREE_REFERENCE_MIN_LENGTH,
        scores=scores, tasks=[ep.task for ep in episodes],
    )


def duration_detector(
    scores: Sequence[np.ndarray], targets: Sequence[np.ndarray], lag: int | None,
    max_delay: float | None = DURATION_DELAY,
) -> DurationCalibration | None:
    """The 'hsmm' detector fitted and tuned on ``targets`` within ``max_delay``; None without a lag or
    with fewer than two segments per episode (nothing to decode)."""
    if lag is None:
        return None
    try:
        duration = calibrate_duration(scores, targets, lag, "align", max_delay=max_delay)
    except DurationModelError as exc:
        LOG.warning("no duration model: %s", exc)
        return None
    return duration if duration.model.subtasks >= 2 else None


def pick_online(threshold: DetectorConfig, threshold_metrics: dict[str, float],
                duration: DurationCalibration | None) -> tuple[DetectorConfig, dict[str, float]]:
    """The online detector (see the module docstring) and the both detectors' validation figures."""
    figures = {f"threshold_val_{k}": float(threshold_metrics[k]) for k in ("align", "f1_tol1")}
    if duration is None:
        return threshold, figures
    figures.update({f"hsmm_val_{k}": float(duration.metrics[k]) for k in ("align", "f1_tol1")})
    better = (duration.metrics["align"] >= threshold_metrics["align"] + DURATION_GAIN
              and duration.metrics["f1_tol1"] >= threshold_metrics["f1_tol1"] - DURATION_GAIN)
    return (duration.config if better else threshold), figures


def prefer(online: DetectorConfig, figures: dict[str, float], name: str, candidate: DetectorConfig,
           metrics: dict[str, float]) -> DetectorConfig:
    """``candidate`` (the detector ``name``: 'head' or 'head_hsmm') when its validation alignment in
    ``metrics`` is higher than that of ``online`` in ``figures``, else ``online``; ``figures`` gains
    the candidate's figures as ``<name>_val_*``."""
    figures.update({f"{name}_val_{k}": float(metrics[k]) for k in ("align", "f1_tol1", "delay_mean")})
    kind = online.mode if online.mode in (DURATION_MODE, HEAD_MODE, HEAD_DURATION_MODE) else "threshold"
    return candidate if metrics["align"] > figures[f"{kind}_val_align"] else online


def tune_head_duration(model: DurationModel, head: BoundaryHead, val_outputs: Sequence[np.ndarray],
                       val_eps: Sequence[Episode], lag: int, max_delay: float | None) -> DurationCalibration:
    """Mode 'head_hsmm' over ``head``'s probabilities of the validation outputs, its threshold tuned
    as the duration decoder's (:func:`~ompn_ros.detect.duration_tuning.calibrate_head_duration`)."""
    rows = [head.probabilities(x) for x in val_outputs]
    return calibrate_head_duration(model, rows, [ep.boundaries for ep in val_eps], lag, "align",
                                   max_delay=max_delay)


def pick_offline(metrics: dict[str, float], min_length: int) -> tuple[OfflineDetector, int]:
    """The offline detector of the best validation alignment in ``metrics`` (``topkc_align``,
    ``topk_align``, ``auto_align``: the constrained Top-K of ``min_length``, Top-K, the automatic
    threshold; the first on ties), and the ``min_length`` it keeps."""
    candidates: list[tuple[float, OfflineDetector]] = [
        (metrics["topkc_align"], "constrained_top_k"),
        (metrics["topk_align"], "top_k"),
        (metrics["auto_align"], "auto_threshold"),
    ]
    best = max(candidates, key=lambda item: item[0])  # the first on ties
    return best[1], int(min_length)


@dataclass(frozen=True)
class HeadCandidate:
    """A fitted boundary head with its decoding chosen and that decoding's validation figures, and
    the model's outputs on the validation episodes (what mode 'head_hsmm' is tuned on)."""

    head: BoundaryHead
    config: DetectorConfig
    metrics: dict[str, float]
    val_outputs: Sequence[np.ndarray]


def pick_head(online: DetectorConfig, figures: dict[str, float], candidate: HeadCandidate | None,
              val_eps: Sequence[Episode], duration: DurationCalibration | None = None, lag: int | None = None,
              max_delay: float | None = None) -> DetectorConfig:
    """The online detector: the boundary head's decoding when its validation alignment is higher, then
    mode 'head_hsmm' (with ``duration``'s model and ``lag``) when its alignment is higher still (see the
    module docstring).  ``figures`` gains their validation figures."""
    if candidate is None:
        return online
    online = prefer(online, figures, HEAD_MODE, candidate.config, candidate.metrics)
    if duration is not None and lag is not None:
        both = tune_head_duration(duration.model, candidate.head, candidate.val_outputs, val_eps, lag,
                                  max_delay)
        online = prefer(online, figures, HEAD_DURATION_MODE, both.config, both.metrics)
    return online


@dataclass(frozen=True)
class Validation:
    """The validation episodes a checkpoint's settings are chosen on: their expansion distributions,
    the episodes, and what the provenance line calls the checkpoint (``what``)."""

    p_hats: Sequence[np.ndarray]
    episodes: Sequence[Episode]
    what: str


def _metrics(calibration: Calibration) -> dict[str, float]:
    return {f"val_{k}": float(v) for k, v in calibration.metrics.items()}


def settings_on_labels(
    val: Validation, objective: Objective, lag: int | None, max_delay: float | None,
    fit_head: Callable[[], HeadCandidate | None], offline: Callable[[], tuple[OfflineDetector, int]],
) -> DetectorSettings:
    """The settings chosen on labelled validation episodes (see the module docstring); ``fit_head``
    fits the boundary head (None: none), ``offline`` chooses the offline detector and its
    ``min_length``; both are called once, in this order."""
    episodes = val.episodes
    scores = scores_from_p_hats(val.p_hats)
    tuned = tune_on_labels(scores, [np.asarray(ep.subtask) for ep in episodes], objective)
    duration = duration_detector(scores, [ep.boundaries for ep in episodes], lag, max_delay)
    online, figures = pick_online(tuned.config, tuned.metrics, duration)
    fitted = fit_head()
    online = pick_head(online, figures, fitted, episodes, duration, lag, max_delay)
    offline_detector, min_length = offline()
    return DetectorSettings(
        online=online,
        offline_detector=offline_detector,
        min_length=min_length,
        source="tuned_on_validation",
        provenance=f"ompn_train: {val.what}, tuned on the labels of {len(episodes)} validation episodes "
        f"(objective {objective}; online mode {online.mode})",
        metrics={**_metrics(tuned), **figures},
        duration_model=None if duration is None else duration.model,
        head=None if fitted is None else fitted.head,
    )


def settings_without_labels(val: Validation, action_type: str, lag: int | None,
                            max_delay: float | None) -> DetectorSettings:
    """The settings calibrated without labels (see the module docstring)."""
    p_hats, episodes = val.p_hats, val.episodes
    scores = scores_from_p_hats(p_hats)
    calibrated = calibrate_without_labels(p_hats, episodes, action_type, scores)
    counts = pooled_counts(p_hats, [ep.task for ep in episodes])
    pooled = [reference_boundaries(p, "pooled_top_k", LABEL_FREE_REFERENCE_MIN_LENGTH, k)
              for p, k in zip(p_hats, counts, strict=True)]
    duration = duration_detector(scores, pooled, lag, max_delay)
    against_pooled = evaluate_grid(scores, [calibrated.config], pooled)[0]
    online, figures = pick_online(calibrated.config, against_pooled, duration)
    return DetectorSettings(
        online=online,
        offline_detector="auto_threshold",
        min_length=LABEL_FREE_MIN_LENGTH,
        source="calibrated_label_free",
        provenance=f"ompn_train: {val.what}, calibrated without labels on {len(episodes)} validation "
        f"episodes (agreement with the {LABEL_FREE_REFERENCE} reference, objective "
        f"{objective_for(action_type)}; online mode {online.mode})",
        metrics={**{k.replace("val_", "agreement_"): v for k, v in _metrics(calibrated).items()},
                 **{k.replace("_val_", "_pooled_"): v for k, v in figures.items()}},
        duration_model=None if duration is None else duration.model,
    )


def choose_settings(
    val: Validation, *, action_type: str, use_labels: bool, lag: int | None = DURATION_LAG,
    max_delay: float | None = DURATION_DELAY, fit_head: Callable[[], HeadCandidate | None] = lambda: None,
    offline: Callable[[], tuple[OfflineDetector, int]],
) -> DetectorSettings:
    """The detector settings of the model whose validation episodes are ``val`` (see the module
    docstring).  Labels are used only when ``use_labels`` and every episode has them.  ``lag``: of
    the 'hsmm' detector (None: fit none); ``max_delay``: the mean delay its threshold may cost."""
    if use_labels and all(ep.subtask is not None for ep in val.episodes):
        return settings_on_labels(val, objective_for(action_type), lag, max_delay, fit_head, offline)
    return settings_without_labels(val, action_type, lag, max_delay)


@dataclass
class Tuned:
    """The chosen online detector, its metrics, the comparison with the other detectors, both
    detectors' validation figures and the duration model of an 'hsmm' choice (else None)."""

    objective: str
    best: DetectorConfig
    metrics: Metrics
    comparison: dict[str, Metrics]
    figures: dict[str, float]
    model: DurationModel | None

    def doc(self) -> dict[str, Any]:
        """What ``ompn_segment --tune`` prints."""
        return {"best": self.best.to_dict(), "metrics": self.metrics, "comparison": self.comparison,
                "choice": self.figures}


def tuning_objective(objective: str | None, domain: str | None) -> str:
    """``objective``, else the domain's (:data:`~ompn_ros.detect.defaults.DEFAULT_OBJECTIVE`), else F1."""
    return objective or DEFAULT_OBJECTIVE.get(domain or "", "f1")


def choose_on_replayed(replays: Sequence[Replayed], episodes: Sequence[Episode], objective: str,
                       lag: int, max_delay: float, long_subtasks: bool = False,
                       head: BoundaryHead | None = None) -> Tuned:
    """The online detector of ``ompn_segment --tune`` on labelled replays (one per episode): the grid's
    threshold detector (:func:`~ompn_ros.detect.tune.choose_on_replays`), the 'hsmm' detector of ``lag``
    within ``max_delay`` mean steps (:func:`pick_online`), then the checkpoint's boundary ``head`` with
    its stored decoding and mode 'head_hsmm' over it when they align better (:func:`prefer`)."""
    threshold, metrics, comparison = choose_on_replays(replays, episodes, objective=objective,
                                                       long_subtasks=long_subtasks)
    duration = duration_detector([r.scores for r in replays], [ep.boundaries for ep in episodes], lag,
                                 max_delay)
    model = None if duration is None else duration.model
    best, figures = pick_online(threshold, metrics, duration)
    if head is not None and head.rule is not None:
        alone = score_online(replays, episodes, head.rule, None, head)
        best = prefer(best, figures, HEAD_MODE, head.rule, alone)
        if duration is not None:
            outputs = [o for o in (getattr(r, "outputs", None) for r in replays) if o is not None]
            both = tune_head_duration(duration.model, head, outputs, episodes, lag, max_delay)
            best = prefer(best, figures, HEAD_DURATION_MODE, both.config, both.metrics)
    if best is not threshold:  # 'online' names what runs: the duration decoder or the head
        metrics = score_online(replays, episodes, best, model, head)
        comparison = {"online": metrics, "online_threshold": comparison.pop("online"), **comparison}
    return Tuned(objective, best, metrics, comparison, figures, model)


def with_tuned(stored: DetectorSettings, best: DetectorConfig, metrics: Metrics, provenance: str,
               duration_model: DurationModel | None = None) -> DetectorSettings:
    """``stored`` with a tuned online detector (and the duration model fitted beside it), its offline
    choices kept; a shipped checkpoint's settings stay the ``'shipped'`` ones.  Only finite metrics
    are kept."""
    measured = {k: float(v) for k, v in metrics.items() if math.isfinite(float(v))}
    source: SettingsSource = "shipped" if stored.source == "shipped" else "tuned_on_validation"
    return dataclasses.replace(stored, online=best, source=source, provenance=provenance, metrics=measured,
                               duration_model=duration_model)


def replay_config() -> DetectorConfig:
    """The detector the replays of a tuning run with (the first of the grid; the tuning reads only the
    replays' scores and outputs, never their events)."""
    return default_grid()[0]


__all__ = [
    "HeadCandidate",
    "Tuned",
    "Validation",
    "calibrate_without_labels",
    "choose_on_replayed",
    "choose_settings",
    "duration_detector",
    "pick_head",
    "pick_offline",
    "pick_online",
    "prefer",
    "replay_config",
    "settings_on_labels",
    "settings_without_labels",
    "tune_head_duration",
    "tuning_objective",
    "with_tuned",
]
