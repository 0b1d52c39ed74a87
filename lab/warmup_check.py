"""``agreement_warmup`` where it was tuned and where it was not: which checkpoint the label-free
selection keeps with the shipped warm-up (100 iterations), without one, and with the warm-up that
this family's own validation labels would have chosen, each scored with the labels it never saw.

Training does not depend on the selection criterion, so a labelled run of :mod:`lab.own_data` logs
at every evaluation both the label-free ``agreement`` and the labelled validation figures
(``log.jsonl``).  Replaying the label-free selection on that log (the trainer's own
:func:`~ompn_ros.train.trainer.eligible` and :func:`~ompn_ros.train.trainer.selection_key`) gives the
evaluation a label-free run would keep; its offline validation F1@1 and alignment (Craft: Top-K,
Dial: the automatic threshold; paper §4) measure the choice on episodes that were neither trained on
nor seen by the selection's criterion.  Only runs the restart rule did not touch qualify: the rule is
off without labels, so a restarted run's log is not what a label-free run would have logged.
Checkpoints between evaluations are not kept, so there are no online figures.

The reference of the transfer table is the family's own best warm-up (:func:`family_best`, over
:data:`GRID`, ranked in the domain's order of the detector's tuning), not "none": without a warm-up
the Dial picks are barely trained models whose offline F1@1 exceeds a trained one's on the expert
family the value was tuned on as much as on the human-like one (docs/design.md#agreement-warm-up).
That best is chosen on the same validation figures it is scored on, so it flatters the reference:
a default that holds against it holds.

    python -m lab.warmup_check --work runs/own_data      # results/agreement_warmup.json
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab.report import study_main
from lab.report_transfer import WARMUP
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.trainer import eligible, selection_key

SHIPPED_WARMUP = 100  # config/train_{craft,dial}.yaml
GRID = tuple(range(0, 201, 20))
"""The warm-ups tried for a family's own best: every evaluation (20 iterations apart) up to 200; it
holds 0 (none) and the shipped value."""
FIGURES = ("offline_f1_1", "offline_align")
ORDER = {"craft": FIGURES, "dial": ("offline_align", "offline_f1_1")}
"""The figure ranked first per domain, as the detector's tuning ranks them (docs/design.md#detector-grid)."""


@dataclass(frozen=True)
class Family:
    name: str
    runs: tuple[str, ...]
    domain: str
    kept_out: str


FAMILIES = (
    Family("Dial, expert, complete bags", tuple(
        "final_dial_complete" + (f"_seed{s}" if s else "") for s in range(5)), "dial",
        "none: seeds 0–1 tuned it (labels hidden), seeds 2–4 did not"),
    Family("Dial, human-like, complete bags", tuple(f"human_dial_complete_seed{s}" for s in range(5, 10)),
           "dial", "the family"),
    Family("Craft full, human-like, complete bags, runs without a restart",
           ("human_craft_full_complete_seed10", "human_craft_full_complete_norestart_seed11",
            "human_craft_full_complete_norestart_seed12"), "craft", "the family"),
)


def label_free_pick(history: Sequence[dict[str, float]], warmup: int) -> dict[str, float]:
    """The evaluation the label-free selection keeps with ``agreement_warmup = warmup`` (the first of
    equal keys, as the trainer keeps it)."""
    cfg = TrainConfig(agreement_warmup=warmup, iterations=int(history[-1]["iteration"]))
    kept = [r for r in history if eligible(cfg, "agreement", int(r["iteration"]))]
    return max(kept, key=lambda r: selection_key(r, "agreement"))


def _figures(pick: dict[str, float]) -> dict[str, float]:
    return {"iteration": int(pick["iteration"]), "offline_f1_1": float(pick["f1_tol1"]),
            "offline_align": float(pick["align"])}


def run_row(run: str, work: Path) -> dict[str, Any]:
    """One run: the iteration and validation figures of each warm-up's pick (those of :data:`GRID`
    under ``"grid"``, keyed by the warm-up)."""
    lines = (work / "runs" / run / "log.jsonl").read_text(encoding="utf-8").splitlines()
    history = [json.loads(line) for line in lines if line.strip()]
    grid = {str(w): _figures(label_free_pick(history, w)) for w in GRID}
    return {"run": run, "evaluations": len(history), "shipped": grid[str(SHIPPED_WARMUP)], "none": grid["0"],
            "grid": grid}


def _mean(picks: Sequence[dict[str, Any]]) -> dict[str, float]:
    return {f: sum(float(p[f]) for p in picks) / len(picks) for f in FIGURES}


def family_best(grid_means: dict[str, dict[str, float]], domain: str) -> int:
    """The warm-up of :data:`GRID` with the best mean figures in the domain's order (:data:`ORDER`);
    of equal ones the smallest."""
    first, second = ORDER[domain]
    return max(GRID, key=lambda w: (grid_means[str(w)][first], grid_means[str(w)][second], -w))


def family_row(family: Family, work: Path) -> dict[str, Any]:
    """Means over the family's runs of the shipped warm-up's pick, no warm-up's, and the family's own
    best warm-up's (``means["family"]``, the warm-up under ``"family_warmup"``, the warm-ups of
    :data:`GRID` with the same means under ``"family_ties"``)."""
    runs = [run_row(r, work) for r in family.runs]
    means = {k: _mean([r[k] for r in runs]) for k in ("shipped", "none")}
    grid = {str(w): _mean([r["grid"][str(w)] for r in runs]) for w in GRID}
    best = family_best(grid, family.domain)
    return {"family": family.name, "seeds": [int(r.rsplit("seed", 1)[1]) if "seed" in r else 0
                                             for r in family.runs],
            "kept_out_of_tuning": family.kept_out, "family_warmup": best,
            "family_ties": [w for w in GRID if grid[str(w)] == grid[str(best)]],
            "changed": sum(r["shipped"]["iteration"] != r["none"]["iteration"] for r in runs),
            "means": {**means, "family": grid[str(best)]}, "grid_means": grid, "runs": runs}


META = {"held_out": "validation episodes of each run: not trained on, and their labels unseen by the "
                    "label-free selection (the family's own best warm-up is chosen on them)",
        "warmup": SHIPPED_WARMUP, "grid": list(GRID)}


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.warmup_check [--work W] [--results R]``: ``R/agreement_warmup.json``."""
    return study_main(argv, "lab.warmup_check", __doc__ or "", WARMUP, META,
                      lambda work: [family_row(f, work) for f in FAMILIES])


if __name__ == "__main__":
    sys.exit(main())
