"""Distilling an ensemble's expansion distributions into one OMPN (``train.distill_from``).

An ensemble of OMPNs segments better than one (docs/design.md#ensembles-and-distillation) because
averaging the members' ``p_hat`` (the distribution over how deep the memory expands, paper §3.1,
``[pi_end, top, ..., bottom]``) smooths out each member's misplaced expansions; it also costs one
step per member.
Distillation (Hinton et al., 2015, "Distilling the Knowledge in a Neural Network") trains a single
student to reproduce the teachers' averaged distribution, at single-model cost when it runs:

* before training, every teacher is run teacher-forced over the training episodes once
  (:func:`teacher_p_hats`, ``O(teachers · frames)``), and the members' ``p_hat`` are averaged per
  step and attached to each episode as ``extras[TEACHER_P_HAT]`` ``[T, n+1]``
  (:func:`with_teacher_targets`; :func:`~ompn_ros.train.batching.collate` pads them);
* the training loss is the behaviour-cloning loss plus ``distill_weight`` times the mean, over the
  real steps, of ``KL(teacher p_hat || student p_hat)`` (:func:`distill_loss`).

Validation, selection and the bundled detector see no teacher: they are the student's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ompn_ros.data.episode import Episode
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.ensemble import is_ensemble, read_ensemble
from ompn_ros.model.errors import CheckpointError, EnsembleError
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.train.batching import TEACHER_P_HAT
from ompn_ros.train.errors import DistillError
from ompn_ros.train.evaluation import teacher_forced_p_hat

P_HAT_FLOOR = 1e-8
"""Smallest probability inside the logarithms of :func:`distill_loss` (keeps them finite)."""


def teacher_paths(sources: Sequence[str]) -> list[Path]:
    """The member checkpoints of ``sources`` (checkpoint directories or ensemble directories)."""
    paths: list[Path] = []
    for source in sources:
        path = Path(source)
        try:
            paths.extend(read_ensemble(path)[0] if is_ensemble(path) else [path])
        except EnsembleError as exc:
            raise DistillError(f"distill_from '{source}': {exc}") from exc
    return paths


def teacher_p_hats(sources: Sequence[str], episodes: Sequence[Episode], student: OMPNConfig,
                   batch_size: int = 64) -> list[np.ndarray]:
    """Per episode, the teachers' teacher-forced ``p_hat`` ``[T, n+1]`` averaged over teachers.

    Raises :class:`DistillError` when a teacher does not load or its memory has another number of
    slots than ``student`` (the distributions would not be comparable)."""
    total: list[np.ndarray] | None = None
    paths = teacher_paths(sources)
    for path in paths:
        try:
            policy, _ = load_checkpoint(path)
        except (CheckpointError, OSError) as exc:
            raise DistillError(f"distill_from '{path}': {exc}") from exc
        if not isinstance(policy, OMPNPolicy):
            raise DistillError(f"distill_from '{path}': not an OMPN checkpoint (arch '{policy.config.arch}')")
        if policy.config.n_slots != student.n_slots or policy.config.sketch_mode != student.sketch_mode:
            raise DistillError(
                f"distill_from '{path}': teacher has n_slots={policy.config.n_slots}, sketch_mode="
                f"'{policy.config.sketch_mode}'; the student has n_slots={student.n_slots}, sketch_mode="
                f"'{student.sketch_mode}'")
        p_hats, _ = teacher_forced_p_hat(policy, episodes, batch_size=batch_size)
        total = p_hats if total is None else [a + b for a, b in zip(total, p_hats, strict=True)]
    if total is None:
        raise DistillError("distill_from names no teacher")
    return [(p / len(paths)).astype(np.float32) for p in total]


def with_teacher_targets(episodes: Sequence[Episode], targets: Sequence[np.ndarray]) -> list[Episode]:
    """Copies of ``episodes`` carrying their target in ``extras[TEACHER_P_HAT]`` (the input is unchanged)."""
    return [replace(ep, extras={**ep.extras, TEACHER_P_HAT: target})
            for ep, target in zip(episodes, targets, strict=True)]


def distill_loss(student_p_hat: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    """Mean over ``mask``'s steps of ``KL(target || student)``; all ``[B, L, n+1]`` (mask ``[B, L]``)."""
    target = target.clamp_min(P_HAT_FLOOR)
    kl = (target * (target.log() - student_p_hat.clamp_min(P_HAT_FLOOR).log())).sum(-1)
    return torch.where(mask, kl, 0.0).sum() / mask.sum().clamp_min(1)


__all__ = ["distill_loss", "teacher_p_hats", "teacher_paths",
           "with_teacher_targets"]
