"""The duration decoder's delay budget on Craft runs it was not set on (human-like, full and partial
observation; expert partial, held-out seeds): the 'hsmm' detector tuned on each run's validation
episodes within the shipped budget (``train.detector_delay``, 6 steps) and without one, scored on
held-out test episodes.

The budget was set on expert Craft, where larger budgets changed nothing (docs/design.md#delay-budget).
Here each run's cached teacher-forced scores (:mod:`lab.detector_selection`; the streaming stepper
gives the same ``p_hat`` to 1e-5) are decoded as ``ompn_train`` decodes them
(:func:`~ompn_ros.detect.calibrate.calibrate_duration`, lag :data:`~ompn_ros.train.detector.DURATION_LAG`,
objective alignment), once with the budget and once without, and the chosen threshold is scored on
test: F1@1, strict alignment, the mean delay of inner boundaries and the share of them published
only at the episode end.  Nothing is trained.

    python -m lab.budget_check --work runs/own_data      # results/delay_budget.json
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lab.detector_selection import _bounds, cached_scores, decoded
from lab.report import study_main
from lab.report_transfer import BUDGET
from ompn_ros.detect.defaults import DURATION_DELAY, DURATION_LAG
from ompn_ros.detect.duration_tuning import calibrate_duration
from ompn_ros.detect.grid import scores_from_p_hats


def _runs(observation: str, bags: Sequence[str] = ("complete", "blank_best2"), prefix: str = "human"
          ) -> tuple[str, ...]:
    return tuple(f"{prefix}_craft_{observation}_{b}_seed{s}" for b in bags for s in range(10, 15))


FAMILIES = (
    ("Craft full, human-like, complete and blank best of 2, seeds 10–14", "the family", _runs("full")),
    ("Craft partial, human-like, complete and blank best of 2, seeds 10–14", "the family", _runs("partial")),
    ("Craft partial, expert, complete, seeds 10–14", "seeds 10–14", _runs("partial", ("complete",), "final")),
)
"""(name, kept out of tuning, runs): the budget was set on expert Craft, full and partial, seeds 0–4."""
FIGURES = ("online_f1_1", "online_align", "delay_mean", "at_end_share")


def run_row(arm: str, work: Path) -> dict[str, Any]:
    """One run: per budget, the threshold validation chose and its test figures."""
    data = cached_scores(arm, work)
    val_scores, val_bounds = scores_from_p_hats(data["val_p"]), _bounds(data["val_l"])
    row: dict[str, Any] = {"arm": arm}
    for name, budget in (("shipped", DURATION_DELAY), ("none", None)):
        cal = calibrate_duration(val_scores, val_bounds, DURATION_LAG, "align", max_delay=budget)
        row[name] = {"threshold": cal.config.high,
                     **decoded(cal.config, cal.model, data["test_p"], data["test_l"])}
    return row


def family_row(work: Path, family: str, kept_out: str, runs: Sequence[str]) -> dict[str, Any]:
    rows = [run_row(r, work) for r in runs]
    means = {k: {f: float(np.mean([r[k][f] for r in rows])) for f in FIGURES} for k in ("shipped", "none")}
    return {"family": family, "kept_out_of_tuning": kept_out,
            "seeds": sorted({int(r.rsplit("seed", 1)[1]) for r in runs}), "means": means, "runs": rows}


META = {"held_out": "test episodes of each bag set (20 %), never trained or tuned on; each threshold "
                    "chosen on the run's own validation episodes", "budget_steps": DURATION_DELAY}


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.budget_check [--work W] [--results R]``: ``R/delay_budget.json``."""
    return study_main(argv, "lab.budget_check", __doc__ or "", BUDGET, META,
                      lambda work: [family_row(work, *family) for family in FAMILIES])


if __name__ == "__main__":
    sys.exit(main())
