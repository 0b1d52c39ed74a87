"""The detector settings ``ompn_train`` bundles with a checkpoint (``detector.json``).

The choice itself is :func:`ompn_ros.detect.choose.choose_settings`, made on the validation
episodes' expansion distributions (teacher-forced; the streaming stepper gives the same ``p_hat`` to
1e-5).  What only training has is supplied here: the boundary head fitted on the labelled training
episodes' outputs (:mod:`ompn_ros.train.boundary_head`) and the offline detector with the best
validation alignment among Top-K, the automatic threshold and the constrained Top-K with its
``min_length`` tuned (:mod:`ompn_ros.train.evaluation`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect.choose import HeadCandidate, Validation, pick_offline
from ompn_ros.detect.choose import choose_settings as choose
from ompn_ros.detect.defaults import DURATION_DELAY, DURATION_LAG
from ompn_ros.detect.settings import DetectorSettings, OfflineDetector, save_detector_settings
from ompn_ros.train.boundary_head import fit_and_choose
from ompn_ros.train.evaluation import decomposition_metrics, tune_min_length

LOG = logging.getLogger("ompn_ros.train")


def _offline_choice(p_hats: Sequence[np.ndarray], episodes: Sequence[Episode]) -> tuple[OfflineDetector, int]:
    """:func:`~ompn_ros.detect.choose.pick_offline` on the validation figures of the offline detectors,
    the constrained Top-K's ``min_length`` tuned on them first."""
    min_length, _ = tune_min_length(p_hats, episodes)
    return pick_offline(decomposition_metrics(p_hats, episodes, min_length=min_length), min_length)


@dataclass(frozen=True)
class HeadData:
    """What the boundary head is fitted on: the model's outputs
    (:func:`~ompn_ros.train.evaluation.teacher_forced_outputs`) on the labelled training episodes and
    on the validation episodes, and the seed of its initialisation."""

    train_outputs: Sequence[np.ndarray]
    train_episodes: Sequence[Episode]
    val_outputs: Sequence[np.ndarray]
    seed: int = 0


def fit_head(data: HeadData | None, val_eps: Sequence[Episode]) -> HeadCandidate | None:
    """The boundary head trained on ``data`` with its decoding chosen on ``val_eps``; None without
    data or with an unlabelled training episode."""
    if data is None or not data.train_episodes or any(ep.subtask is None for ep in data.train_episodes):
        return None
    choice = fit_and_choose(data.train_outputs, data.train_episodes, data.val_outputs, val_eps, data.seed)
    return HeadCandidate(choice.head, choice.config, choice.metrics, data.val_outputs)


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
    """:func:`ompn_ros.detect.choose.choose_settings` on the validation ``p_hats`` of ``episodes``, with
    the boundary head fitted on ``head`` (None: none) and the offline detector chosen on them.
    ``what`` names the checkpoint in the provenance line."""
    return choose(
        Validation(p_hats, episodes, what), action_type=action_type, use_labels=use_labels, lag=lag,
        max_delay=max_delay, fit_head=lambda: fit_head(head, episodes),
        offline=lambda: _offline_choice(p_hats, episodes),
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


__all__ = ["HeadData", "bundle", "choose_settings", "fit_head"]
