"""The duration decoder over the boundary head (mode 'head_hsmm') on runs it was not designed on
(docs/experiments.md §53).

Each run of :mod:`lab.own_data` (trained by ``ompn_train`` with its boundary head) is scored on its
held-out test episodes through the node's segmenter by :func:`lab.head_check.check_run`: the detector
``ompn_train`` chose before mode 'head_hsmm' (*previous*), mode 'head_hsmm' with its threshold tuned on
validation, and ``ompn_train``'s choice today (*now*).  The offline figure is the run's own (the
paper's Top-K on Craft, :mod:`lab.own_data`).  Rows are cached in ``<work>/head_check/<arm>.json``.

    python -m lab.head_duration --work runs/own_data --results results   # results/head_duration.json
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lab.head_check import check_run
from lab.report import study_main

RESULTS = "head_duration.json"
FAMILIES: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("Craft partial, expert, seeds 10–11", "design",
     tuple(f"final_craft_partial_complete_seed{s}" for s in (10, 11))),
    ("Craft partial, expert, seeds 12–14", "held out",
     tuple(f"final_craft_partial_complete_seed{s}" for s in (12, 13, 14))),
    ("Craft partial, human-like, seeds 10–14", "kept out",
     tuple(f"human_craft_partial_complete_seed{s}" for s in range(10, 15))),
    ("Craft full, expert, seeds 10–14", "kept out",
     tuple(f"final_craft_full_complete_seed{s}" for s in range(10, 15))),
    ("Craft full, human-like, seeds 10–14", "kept out",
     tuple(f"human_craft_full_complete_seed{s}" for s in range(10, 15))),
    ("Dial, expert, seeds 1–4", "kept out", tuple(f"final_dial_complete_seed{s}" for s in range(1, 5))),
    ("Dial, human-like, seeds 5–9", "kept out", tuple(f"human_dial_complete_seed{s}" for s in range(5, 10))),
)
DETECTORS = ("previous", "head_hsmm", "head_hsmm_any_delay", "now")
META = {
    "design": "expert Craft partial seeds 10–11 (the evidence's weight was fixed at 1 there)",
    "budget": "train.detector_lag 1, mean delay at most train.detector_delay 6 steps",
}


def cached_row(arm: str, work: Path) -> dict[str, Any]:
    """:func:`check_run` of ``arm`` with its offline figures, cached in ``<work>/head_check/<arm>.json``."""
    target = work / "head_check" / f"{arm}.json"
    if not target.is_file():
        trained = json.loads((work / "arms" / f"{arm}.json").read_text(encoding="utf-8"))
        row = {**check_run(arm, work), "offline": {"f1_tol1": trained["offline_f1_1"],
                                                   "align": trained["offline_align"]}}
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(row, indent=1) + "\n", encoding="utf-8")
    return dict(json.loads(target.read_text(encoding="utf-8")))


def _mean(rows: Sequence[dict[str, Any]], key: str) -> dict[str, float] | None:
    if not all(key in r for r in rows):
        return None
    fields = rows[0][key]
    return {k: float(np.nanmean([r[key][k] for r in rows])) for k in fields}


def family_rows(work: Path) -> list[dict[str, Any]]:
    """One row per family whose runs are all trained in ``work``: means and the runs."""
    families = []
    for family, role, arms in FAMILIES:
        if not all((work / "arms" / f"{arm}.json").is_file() for arm in arms):
            print(f"head_duration: skipping {family}: not every run is trained", file=sys.stderr)
            continue
        rows = [cached_row(arm, work) for arm in arms]
        for row in rows:  # the run's own online detector: the threshold detector tuned on its labels
            trained = json.loads((work / "arms" / f"{row['arm']}.json").read_text(encoding="utf-8"))
            row["threshold"] = {"f1_tol1": trained["online_f1_1"], "align": trained["online_align"]}
        means = {key: _mean(rows, key) for key in ("offline", "threshold", *DETECTORS)}
        means["now_head_hsmm_runs"] = {"runs": sum(r["modes"]["now"] == "head_hsmm" for r in rows)}
        seeds = [int(arm.rsplit("seed", 1)[1]) for arm in arms]
        families.append({"family": family, "role": role, "runs": len(rows), "seeds": seeds, "means": means,
                         "rows": rows})
    return families


def main(argv: list[str] | None = None) -> int:
    torch.set_num_threads(1)
    return study_main(argv, "lab.head_duration", __doc__, RESULTS, META, family_rows)


if __name__ == "__main__":
    sys.exit(main())
