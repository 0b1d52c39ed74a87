"""``final_observation: auto`` on the lab's Dial arms: per seed, the run whose row T was extrapolated
and the one whose row T was copied, the one validation prefers kept, scored on held-out test episodes
against complete bags (docs/experiments.md §48).

:mod:`ompn_ros.app.final_choice` trains each option on the same split with the same seed, which is
what the arms ``*_extrapolate_seed<k>`` and ``*_duplicate_seed<k>`` of :mod:`lab.own_data` are, so
the choice is replayed here from their checkpoints, nothing is trained.  Each run's online detector
is the threshold setting its validation labels pick under one standard error (the tuning of
``ompn_train``; these runs' tuning never picked the 'hsmm' detector), from the teacher-forced scores
:mod:`lab.detector_selection` caches; the options are then compared as ``ompn_train`` compares them
(:func:`~ompn_ros.detect.tune.pick_within_error` on the two runs' validation figures).  Offline
figures are the own-data table's: the automatic threshold's F1@1 and alignment (authors' decoding),
on the same test episodes.

    python -m lab.final_auto --work runs/own_data        # results/final_auto.json and the README
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lab.detector_selection import _bounds, _grid_rows, cached_scores, one_standard_error, validation
from lab.report import study_main
from lab.report_final_auto import FINAL_AUTO
from ompn_ros.detect.offline import auto_threshold_boundaries
from ompn_ros.detect.tune import default_grid, pick_within_error
from ompn_ros.metrics import alignment_accuracy, mean_f1

OBJECTIVE = "align"  # Dial's tuning objective (ompn_ros.detect.tune.DEFAULT_OBJECTIVE)
FIGURES = ("offline_f1_1", "offline_align", "online_f1_1", "online_align")


@dataclass(frozen=True)
class Family:
    """Seeds of one data family: per option the arm pattern, and the complete bags' arm pattern."""

    name: str
    role: str
    kept_out: str
    seeds: tuple[int, ...]
    options: tuple[tuple[str, str], ...]
    reference: str


FAMILIES = (
    Family("Dial, human-like", "kept out of every tuning; `duplicate` was proposed after seeds 5–7",
           "the family; seeds 8–9 for the option set", tuple(range(5, 10)),
           (("extrapolate", "human_dial_extrapolate_seed{seed}"),
            ("duplicate", "human_dial_duplicate_seed{seed}")),
           "human_dial_complete_seed{seed}"),
    Family("Dial, expert", "the seeds `extrapolate` was chosen on",
           "none: the seeds extrapolate was chosen on", tuple(range(5)),
           (("extrapolate", "final_dial_extrapolate_seed{seed}"),
            ("duplicate", "final_dial_duplicate_seed{seed}")),
           "final_dial_complete_seed{seed}"),
)


def arm_name(pattern: str, seed: int) -> str:
    return pattern.format(seed=seed).replace("_seed0", "")


def offline_figures(p_hats: Sequence[np.ndarray], labels: Sequence[np.ndarray]) -> dict[str, float]:
    """The automatic threshold's F1@1 and alignment (authors' decoding), K = the true count: Dial's
    offline detector (paper Algorithm 2), as the own-data table scores it."""
    bounds = _bounds(list(labels))
    auto = [auto_threshold_boundaries(p, len(b))[0] for p, b in zip(p_hats, bounds, strict=True)]
    return {"offline_f1_1": mean_f1(auto, bounds, 1).f1,
            "offline_align": alignment_accuracy(auto, list(labels), "authors")}


def score_run(arm: str, work: Path) -> dict[str, Any]:
    """One run: its validation pick (one standard error), the pick's validation figures per episode,
    and its test figures."""
    data, grid = cached_scores(arm, work), default_grid()
    val = validation(data["val_p"], data["val_l"], grid)
    g = one_standard_error(val, OBJECTIVE)
    test = _grid_rows(data["test_p"], data["test_l"], grid)[g]
    return {"arm": arm, "config": repr(grid[g]), "val": val.rows[g], "val_per_episode": val.per_episode(g),
            "lengths": val.lengths,
            "test": {**offline_figures(data["test_p"], data["test_l"]),
                     "online_f1_1": test["f1_tol1"], "online_align": test["align_strict"]}}


def seed_row(family: Family, seed: int, work: Path) -> dict[str, Any]:
    """Per option its run, the option validation keeps, and the complete bags' run of the seed."""
    runs = {option: score_run(arm_name(pattern, seed), work) for option, pattern in family.options}
    names = list(runs)
    kept = names[pick_within_error([runs[n]["val"] for n in names], OBJECTIVE,  # type: ignore[arg-type]
                                   lambda g: runs[names[g]]["val_per_episode"], runs[names[0]]["lengths"])]
    reference = score_run(arm_name(family.reference, seed), work)
    return {"seed": seed, "kept": kept,
            "options": {n: {"arm": r["arm"], "val_f1_1": r["val"]["f1_tol1"],
                            "val_align": r["val"]["align_strict"], **r["test"]} for n, r in runs.items()},
            "auto": runs[kept]["test"], "complete": reference["test"]}


def _means(rows: Sequence[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in FIGURES}


def family_row(family: Family, work: Path) -> dict[str, Any]:
    """The family's seeds, and means of auto, each option alone and complete bags."""
    seeds = [seed_row(family, s, work) for s in family.seeds]
    means = {"auto": _means([s["auto"] for s in seeds]), "complete": _means([s["complete"] for s in seeds])}
    for option, _ in family.options:
        means[option] = _means([s["options"][option] for s in seeds])
    return {"family": family.name, "role": family.role, "kept_out_of_tuning": family.kept_out,
            "seeds": list(family.seeds),
            "kept": {o: sum(s["kept"] == o for s in seeds) for o, _ in family.options},
            "means": means, "per_seed": seeds}


META = {"held_out": "test episodes of each bag set (20 %, complete bags), never trained or tuned on; "
                    "the option is kept on the runs' own validation episodes",
        "detector": "each run's online threshold detector picked on validation under one standard error"}


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.final_auto [--work W] [--results R]``: ``R/final_auto.json``."""
    return study_main(argv, "lab.final_auto", __doc__ or "", FINAL_AUTO, META,
                      lambda work: [family_row(f, work) for f in FAMILIES])


if __name__ == "__main__":
    sys.exit(main())
