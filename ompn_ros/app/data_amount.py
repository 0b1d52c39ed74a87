"""Is the data likely enough?  What ``ompn_train`` says before and after training.

The read summary gets a ``data:`` block (:meth:`DataAmount.lines`): demonstrations for training and
validation, steps per subtask when the data has labels, and how the count compares with the fewest
demonstrations any measured run trained on.  After training, :func:`expectation` says what to expect
of the checkpoint and what its selection figure means: the label-free ``agreement`` measures how
well the online detector repeats the model's own whole-episode segmentation, not whether that
segmentation is right.

The reference figures are the smallest training sets measured (docs/design.md#how-much-data); below
them nothing was measured, so the summary says so rather than promising a result.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ompn_ros.data.episode import Episode

FEWEST_LABELLED = 270
"""Training demonstrations of the smallest measured run with labels: a robot-like Dial arm, 300
recorded with 30 for validation, held-out online alignment 0.93 (docs/design.md#how-much-data)."""
FEWEST_LABEL_FREE = 576
"""Training demonstrations of the smallest measured run without labels (Dial, 64 for validation):
online alignment 0.96 and 0.77 on its two seeds (docs/design.md#how-much-data)."""
FEWEST_VALIDATION = 30
"""Validation demonstrations of the smallest measured run: checkpoint selection, early stopping and
the detector's calibration read only these."""


@dataclass(frozen=True)
class DataAmount:
    """How much data a run trains on (:func:`data_amount`)."""

    demonstrations: int
    train: int
    validation: int
    labelled: bool
    steps: int
    subtasks: int  # labelled segments over all episodes (0 without labels)

    @property
    def steps_per_subtask(self) -> float:
        return self.steps / self.subtasks if self.subtasks else 0.0

    @property
    def fewest_measured(self) -> int:
        return FEWEST_LABELLED if self.labelled else FEWEST_LABEL_FREE

    @property
    def likely_enough(self) -> bool:
        """At least as many training and validation demonstrations as the smallest measured run."""
        return self.train >= self.fewest_measured and self.validation >= FEWEST_VALIDATION

    def lines(self) -> list[str]:
        """The ``data:`` block of the read summary."""
        kind = "with labels" if self.labelled else "without labels"
        lines = [f"data: {self.demonstrations} demonstration(s), {self.train} for training and "
                 f"{self.validation} for validation, {kind}"]
        if self.subtasks:
            lines.append(f"  {self.subtasks} labelled subtask(s), {self.steps_per_subtask:.0f} steps per "
                         "subtask on average")
        if self.likely_enough:
            lines.append(f"  likely enough: the smallest measured run {kind} trained on "
                         f"{self.fewest_measured} (docs/design.md#how-much-data)")
            return lines
        lines.append(f"  likely too few: no run {kind} was measured on fewer than {self.fewest_measured} "
                     f"training and {FEWEST_VALIDATION} validation demonstrations; expect subtask ends to be "
                     "missed and record more (docs/design.md#how-much-data)")
        return lines

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "steps_per_subtask": round(self.steps_per_subtask, 1),
                "fewest_measured": self.fewest_measured, "likely_enough": self.likely_enough}


def data_amount(episodes: Sequence[Episode], val_ratio: float, labelled: bool) -> DataAmount:
    """The amount of ``episodes`` split with ``val_ratio`` (the trainer's rule: ``round(val_ratio · N)``
    for validation, at least one for training); ``labelled``: whether validation labels select."""
    n = len(episodes)
    validation = min(round(val_ratio * n), n - 1) if n else 0
    steps = sum(int(ep.actions.shape[0]) for ep in episodes)
    subtasks = sum(_segments(ep.subtask) for ep in episodes if ep.subtask is not None)
    return DataAmount(n, n - validation, validation, labelled, steps, subtasks)


def _segments(labels: np.ndarray) -> int:
    """Runs of equal labels in one episode."""
    return int(len(labels) > 0) + int(np.count_nonzero(labels[1:] != labels[:-1]))


def expectation(amount: DataAmount, selection: str, best: Mapping[str, float]) -> list[str]:
    """What to expect of the trained checkpoint, given the data and its best validation figures."""
    lines = []
    if selection == "agreement":
        value = best.get("agreement", float("nan"))
        lines.append(
            f"label-free agreement {value:.2f}: how well the online detector repeats this model's own "
            "segmentation, not whether the segmentation is right (a barely trained model scored 0.89 "
            "where labels gave 0.27); only labels measure it: label a few demonstrations' subtasks "
            "and pass them, or check the boundaries of `ompn_segment --plot`"
        )
    elif "align" in best:
        lines.append(f"validation alignment {best['align']:.2f} on {amount.validation} labelled "
                     "demonstration(s): the share of steps given the right subtask")
    if not amount.likely_enough:
        lines.append(
            f"{amount.train} training demonstration(s): fewer than any measured run "
            f"({amount.fewest_measured}{'' if amount.labelled else ' without labels'}); expect missed "
            "subtask ends, especially live, and record more demonstrations (docs/design.md#how-much-data)"
        )
    return lines


__all__ = ["FEWEST_LABELLED", "FEWEST_LABEL_FREE", "FEWEST_VALIDATION", "DataAmount", "data_amount",
           "expectation"]
