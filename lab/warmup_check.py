"""``agreement_warmup`` on human-like runs: which checkpoint the label-free selection keeps with the
shipped warm-up (100 iterations) and without it, scored with the labels it never saw.

Training does not depend on the selection criterion, so a labelled run of :mod:`lab.own_data` logs
at every evaluation both the label-free ``agreement`` and the labelled validation figures
(``log.jsonl``).  Replaying the label-free selection on that log (the trainer's own
:func:`~ompn_ros.train.trainer.eligible` and :func:`~ompn_ros.train.trainer.selection_key`) gives the
evaluation a label-free run would keep; its offline validation F1@1 and alignment (Craft: Top-K,
Dial: the automatic threshold; paper §4) measure the choice on episodes that were neither trained on
nor seen by the selection's criterion.  Only runs the restart rule did not touch qualify: the rule is
off without labels, so a restarted run's log is not what a label-free run would have logged.
Checkpoints between evaluations are not kept, so there are no online figures.

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
FIGURES = ("offline_f1_1", "offline_align")


@dataclass(frozen=True)
class Family:
    name: str
    runs: tuple[str, ...]


FAMILIES = (
    Family("Dial, human-like, complete bags", tuple(f"human_dial_complete_seed{s}" for s in range(5, 10))),
    Family("Craft full, human-like, complete bags, runs without a restart",
           ("human_craft_full_complete_seed10", "human_craft_full_complete_norestart_seed11",
            "human_craft_full_complete_norestart_seed12")),
)


def label_free_pick(history: Sequence[dict[str, float]], warmup: int) -> dict[str, float]:
    """The evaluation the label-free selection keeps with ``agreement_warmup = warmup`` (the first of
    equal keys, as the trainer keeps it)."""
    cfg = TrainConfig(agreement_warmup=warmup, iterations=int(history[-1]["iteration"]))
    kept = [r for r in history if eligible(cfg, "agreement", int(r["iteration"]))]
    return max(kept, key=lambda r: selection_key(r, "agreement"))


def run_row(run: str, work: Path) -> dict[str, Any]:
    """One run: the iteration and validation figures of each warm-up's pick."""
    lines = (work / "runs" / run / "log.jsonl").read_text(encoding="utf-8").splitlines()
    history = [json.loads(line) for line in lines if line.strip()]
    row: dict[str, Any] = {"run": run, "evaluations": len(history)}
    for name, warmup in (("shipped", SHIPPED_WARMUP), ("none", 0)):
        pick = label_free_pick(history, warmup)
        row[name] = {"iteration": int(pick["iteration"]), "offline_f1_1": float(pick["f1_tol1"]),
                     "offline_align": float(pick["align"])}
    return row


def family_row(family: Family, work: Path) -> dict[str, Any]:
    runs = [run_row(r, work) for r in family.runs]
    means = {k: {f: sum(r[k][f] for r in runs) / len(runs) for f in FIGURES} for k in ("shipped", "none")}
    return {"family": family.name, "seeds": [int(r.rsplit("seed", 1)[1]) for r in family.runs],
            "changed": sum(r["shipped"]["iteration"] != r["none"]["iteration"] for r in runs),
            "means": means, "runs": runs}


META = {"held_out": "validation episodes of each run: not trained on, and their labels unseen by the "
                    "label-free selection", "warmup": SHIPPED_WARMUP}


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.warmup_check [--work W] [--results R]``: ``R/agreement_warmup.json``."""
    return study_main(argv, "lab.warmup_check", __doc__ or "", WARMUP, META,
                      lambda work: [family_row(f, work) for f in FAMILIES])


if __name__ == "__main__":
    sys.exit(main())
