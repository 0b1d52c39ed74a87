"""The detector settings a trained checkpoint carries (``detector.json``), chosen on validation episodes.

At the end of training :func:`choose_settings` picks, from the validation episodes' expansion
distributions (teacher-forced; the streaming stepper gives the same ``p_hat`` to 1e-5):

* with labels: the online detector tuned on them (:func:`~ompn_ros.detect.calibrate.tune_on_labels`,
  the grid and objective of ``ompn_segment --tune``) and the offline detector with the best
  validation alignment among Top-K, the automatic threshold (Lu et al., ICLR 2021, Algorithm 2) and
  the constrained Top-K with its ``min_length`` tuned too;
* without labels (or with ``train.labels: none``): the online detector calibrated to agree with
  the model's own whole-episode segmentation
  (:func:`~ompn_ros.detect.calibrate.calibrate_label_free`), and the automatic threshold offline,
  the only offline detector that needs no number of subtasks.

The objective follows the domain's headline metric: boundary F1 for discrete actions (Craft),
alignment for continuous ones (Dial).

Both ways also fit the duration decoder (mode 'hsmm', :mod:`ompn_ros.detect.duration`) on the same
targets (the labels, or the pooled constrained Top-K without them) and tune its threshold for
alignment at ``train.detector_lag``, with a mean delay of at most ``train.detector_delay`` steps; the
checkpoint keeps the model.  It becomes the online detector
when its validation alignment beats the threshold detector's by :data:`DURATION_GAIN` with F1@1 at
most :data:`DURATION_GAIN` lower (docs/design.md#duration-decoder).

With labels, and the training episodes' outputs given, the learned boundary head (mode 'head',
:mod:`ompn_ros.train.boundary_head`) is trained too and kept with the checkpoint; it becomes the
online detector when its validation alignment is higher than that of the detector chosen above
(docs/design.md#boundary-head).  With the head and the duration model both fitted, the duration
decoder over the head (mode 'head_hsmm', :mod:`ompn_ros.detect.head_duration`) has its threshold
tuned the same way, and becomes the online detector when its validation alignment is higher still
(docs/design.md#duration-decoder-over-the-head).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect.calibrate import (
    Calibration,
    DurationCalibration,
    Objective,
    Reference,
    calibrate_duration,
    calibrate_head_duration,
    calibrate_label_free,
    evaluate_grid,
    pooled_counts,
    reference_boundaries,
    scores_from_p_hats,
    tune_on_labels,
)
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.errors import DurationModelError
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import DURATION_DELAY as DURATION_DELAY  # defined with the detector, light
from ompn_ros.detect.online import DURATION_LAG as DURATION_LAG
from ompn_ros.detect.online import DURATION_MODE, HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.detect.settings import DetectorSettings, OfflineDetector, save_detector_settings
from ompn_ros.train.boundary_head import HeadChoice, fit_and_choose
from ompn_ros.train.evaluation import decomposition_metrics, tune_min_length

LOG = logging.getLogger("ompn_ros.train")
LABEL_FREE_REFERENCE: Reference = "onset_and_pooled"
"""The whole-episode detector the label-free calibration agrees with
(docs/design.md#label-free-calibration)."""
LABEL_FREE_REFERENCE_MIN_LENGTH = 3
"""``min_length`` of its pooled constrained Top-K (docs/design.md#label-free-calibration)."""
LABEL_FREE_MIN_LENGTH = 2
"""``min_length`` stored with label-free settings (the constrained Top-K's default)."""
DURATION_GAIN = 0.01
"""Validation alignment the 'hsmm' detector must gain, and F1@1 it may lose at most, to be chosen."""


def objective_for(action_type: str) -> Objective:
    """Boundary F1 for discrete actions (Craft's headline metric), alignment for continuous (Dial)."""
    return "f1" if action_type == "discrete" else "align"


def _offline_choice(p_hats: Sequence[np.ndarray], episodes: Sequence[Episode]) -> tuple[OfflineDetector, int]:
    min_length, _ = tune_min_length(p_hats, episodes)
    metrics = decomposition_metrics(p_hats, episodes, min_length=min_length)
    candidates: list[tuple[float, OfflineDetector]] = [
        (metrics["topkc_align"], "constrained_top_k"),
        (metrics["topk_align"], "top_k"),
        (metrics["auto_align"], "auto_threshold"),
    ]
    best = max(candidates, key=lambda item: item[0])  # the first on ties
    return best[1], int(min_length)


def _metrics(calibration: Calibration) -> dict[str, float]:
    return {f"val_{k}": float(v) for k, v in calibration.metrics.items()}


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


@dataclass(frozen=True)
class HeadData:
    """What the boundary head is fitted on: the model's outputs
    (:func:`~ompn_ros.train.evaluation.teacher_forced_outputs`) on the labelled training episodes and
    on the validation episodes, and the seed of its initialisation."""

    train_outputs: Sequence[np.ndarray]
    train_episodes: Sequence[Episode]
    val_outputs: Sequence[np.ndarray]
    seed: int = 0


def pick_head(online: DetectorConfig, figures: dict[str, float], data: HeadData | None,
              val_eps: Sequence[Episode], duration: DurationCalibration | None = None, lag: int | None = None,
              max_delay: float | None = None) -> tuple[DetectorConfig, HeadChoice | None]:
    """The online detector: the boundary head's decoding when its validation alignment is higher, then
    mode 'head_hsmm' (with ``duration``'s model and ``lag``) when its alignment is higher still (see the
    module docstring); the head fitted, if any.  ``figures`` gains their validation figures."""
    if data is None or not data.train_episodes or any(ep.subtask is None for ep in data.train_episodes):
        return online, None
    choice = fit_and_choose(data.train_outputs, data.train_episodes, data.val_outputs, val_eps, data.seed)
    online = prefer(online, figures, HEAD_MODE, choice.config, choice.metrics)
    if duration is not None and lag is not None:
        both = tune_head_duration(duration.model, choice.head, data.val_outputs, val_eps, lag, max_delay)
        online = prefer(online, figures, HEAD_DURATION_MODE, both.config, both.metrics)
    return online, choice


def tune_head_duration(model: DurationModel, head: BoundaryHead, val_outputs: Sequence[np.ndarray],
                       val_eps: Sequence[Episode], lag: int, max_delay: float | None) -> DurationCalibration:
    """Mode 'head_hsmm' over ``head``'s probabilities of the validation outputs, its threshold tuned
    as the duration decoder's (:func:`~ompn_ros.detect.calibrate.calibrate_head_duration`)."""
    rows = [head.probabilities(x) for x in val_outputs]
    return calibrate_head_duration(model, rows, [ep.boundaries for ep in val_eps], lag, "align",
                                   max_delay=max_delay)


def prefer(online: DetectorConfig, figures: dict[str, float], name: str, candidate: DetectorConfig,
           metrics: dict[str, float]) -> DetectorConfig:
    """``candidate`` (the detector ``name``: 'head' or 'head_hsmm') when its validation alignment in
    ``metrics`` is higher than that of ``online`` in ``figures``, else ``online``; ``figures`` gains
    the candidate's figures as ``<name>_val_*``."""
    figures.update({f"{name}_val_{k}": float(metrics[k]) for k in ("align", "f1_tol1", "delay_mean")})
    kind = online.mode if online.mode in (DURATION_MODE, HEAD_MODE, HEAD_DURATION_MODE) else "threshold"
    return candidate if metrics["align"] > figures[f"{kind}_val_align"] else online


def choose_settings(
    p_hats: Sequence[np.ndarray],
    episodes: Sequence[Episode],
    *,
    action_type: str,
    use_labels: bool,
    what: str,
    lag: int | None = DURATION_LAG,
    max_delay: float | None = DURATION_DELAY,
    head: HeadData | None = None,
) -> DetectorSettings:
    """Detector settings for the model whose validation ``p_hats`` are given (see module docstring).

    ``what`` names the checkpoint in the provenance line.  Labels are used only when ``use_labels``
    and every episode has them.  ``lag``: of the 'hsmm' detector (None: fit none); ``max_delay``: the
    mean delay its threshold may cost; ``head``: what the boundary head is fitted on (None: none).
    """
    objective = objective_for(action_type)
    labelled = use_labels and all(ep.subtask is not None for ep in episodes)
    scores = scores_from_p_hats(p_hats)
    if labelled:
        tuned = tune_on_labels(scores, [np.asarray(ep.subtask) for ep in episodes], objective)
        duration = duration_detector(scores, [ep.boundaries for ep in episodes], lag, max_delay)
        online, figures = pick_online(tuned.config, tuned.metrics, duration)
        online, fitted = pick_head(online, figures, head, episodes, duration, lag, max_delay)
        offline, min_length = _offline_choice(p_hats, episodes)
        return DetectorSettings(
            online=online,
            offline_detector=offline,
            min_length=min_length,
            source="tuned_on_validation",
            provenance=f"ompn_train: {what}, tuned on the labels of {len(episodes)} validation episodes "
            f"(objective {objective}; online mode {online.mode})",
            metrics={**_metrics(tuned), **figures},
            duration_model=None if duration is None else duration.model,
            head=None if fitted is None else fitted.head,
        )
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
        provenance=f"ompn_train: {what}, calibrated without labels on {len(episodes)} validation episodes "
        f"(agreement with the {LABEL_FREE_REFERENCE} reference, objective {objective}; online mode "
        f"{online.mode})",
        metrics={**{k.replace("val_", "agreement_"): v for k, v in _metrics(calibrated).items()},
                 **{k.replace("_val_", "_pooled_"): v for k, v in figures.items()}},
        duration_model=None if duration is None else duration.model,
    )


def bundle(
    checkpoint_dir: Path,
    p_hats: Sequence[np.ndarray],
    episodes: Sequence[Episode],
    *,
    action_type: str,
    use_labels: bool,
    lag: int | None = DURATION_LAG,
    max_delay: float | None = DURATION_DELAY,
    head: HeadData | None = None,
) -> DetectorSettings:
    """Choose the settings (:func:`choose_settings`) and write ``checkpoint_dir/detector.json``."""
    settings = choose_settings(
        p_hats,
        episodes,
        action_type=action_type,
        use_labels=use_labels,
        what=f"checkpoint {checkpoint_dir.name}/",
        lag=lag,
        max_delay=max_delay,
        head=head,
    )
    save_detector_settings(checkpoint_dir, settings)
    LOG.info("%s: %s", checkpoint_dir / "detector.json", settings.describe())
    return settings


__all__ = [
    "DURATION_DELAY",
    "DURATION_GAIN",
    "DURATION_LAG",
    "LABEL_FREE_REFERENCE",
    "LABEL_FREE_REFERENCE_MIN_LENGTH",
    "HeadData",
    "bundle",
    "calibrate_without_labels",
    "choose_settings",
    "duration_detector",
    "objective_for",
    "pick_head",
    "pick_online",
    "prefer",
    "tune_head_duration",
]
