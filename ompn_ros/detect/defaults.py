"""The defaults of the detector choice (:mod:`ompn_ros.detect.choose`): what a checkpoint runs when
nothing was chosen, and the numbers the choice itself is made with.

Light on purpose (no numpy): a command's ``--help`` shows these defaults without loading the
detectors.  See docs/design.md#duration-decoder, #delay-budget and #label-free-calibration.
"""

from __future__ import annotations

from typing import Final, Literal

Objective = Literal["f1", "align"]
OBJECTIVES: tuple[Objective, ...] = ("f1", "align")
"""What tuning the online detector maximises first: boundary F1 at tolerance 1, or strict alignment
accuracy."""
DEFAULT_OBJECTIVE: dict[str, Objective] = {"craft": "f1", "dial": "align"}
"""Per domain, the paper's headline metric (Craft: F1 of the boundaries; Dial: alignment)."""
DURATION_LAG = 1
"""Default ``train.detector_lag`` and ``ompn_segment --lag``: the 'hsmm' detector publishes a
boundary at least ``lag + 1`` steps after its step (docs/design.md#duration-decoder)."""
DURATION_DELAY = 6.0
"""Default ``train.detector_delay`` and ``ompn_segment --max-delay``: the mean delay in steps the
'hsmm' detector's threshold may cost (docs/design.md#delay-budget)."""
DURATION_GAIN = 0.01
"""Validation alignment the 'hsmm' detector must gain, and F1@1 it may lose at most, to be chosen."""
LABEL_FREE_REFERENCE: Final = "onset_and_pooled"
"""The whole-episode detector the label-free calibration agrees with (one of
:data:`ompn_ros.detect.reference.REFERENCES`; docs/design.md#label-free-calibration)."""
LABEL_FREE_REFERENCE_MIN_LENGTH = 3
"""``min_length`` of its pooled constrained Top-K (docs/design.md#label-free-calibration)."""
LABEL_FREE_MIN_LENGTH = 2
"""``min_length`` stored with label-free settings (the constrained Top-K's default)."""
DEFAULT_DONE_THRESHOLD = 0.5
"""``ompn_node`` publishes the done action when π_end exceeds it (settings without a choice)."""
DEFAULT_MIN_LENGTH = 2
"""The constrained Top-K's minimum subtask length in steps (settings without a choice)."""


def objective_for(action_type: str) -> Objective:
    """Boundary F1 for discrete actions (Craft's headline metric), alignment for continuous (Dial)."""
    return "f1" if action_type == "discrete" else "align"


__all__ = [
    "DEFAULT_DONE_THRESHOLD",
    "DEFAULT_MIN_LENGTH",
    "DEFAULT_OBJECTIVE",
    "DURATION_DELAY",
    "DURATION_GAIN",
    "DURATION_LAG",
    "LABEL_FREE_MIN_LENGTH",
    "LABEL_FREE_REFERENCE",
    "LABEL_FREE_REFERENCE_MIN_LENGTH",
    "OBJECTIVES",
    "Objective",
    "objective_for",
]
