"""The "Detector selection" section of ``results/README.md``, from ``detector_selection.json``
(:mod:`lab.detector_selection`).

Metrics are fractions in the file and percentages in the table; gaps in percentage points.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .report_own import gaps, pair

SELECTION = "detector_selection.json"


def _line(row: dict[str, Any]) -> str:
    means = row["means"]
    old, new, best = (means[k] for k in ("previous", "one_se", "test_oracle"))
    return (f"| {row['family']} | {row['role']} | {row['runs']} | {row['changed']} | "
            f"{pair(old['f1_1'], old['align'])} | {pair(new['f1_1'], new['align'])} | "
            f"{gaps((new['f1_1'], new['align']), (old['f1_1'], old['align']))} | "
            f"{pair(best['f1_1'], best['align'])} |")


def selection_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The detector-selection table, when ``detector_selection.json`` exists."""
    path = results_dir / SELECTION
    if not path.is_file():
        return []
    doc = json.loads(path.read_text(encoding="utf-8"))
    meta = doc["meta"]
    lines = [
        f"{'#' * level} Detector selection: one standard error",
        "",
        f"Made by `{' '.join(meta['command'])}` on {meta['date']}: the online threshold detector each run's "
        f"validation labels choose, scored on {meta['held_out']}. *previous*: the largest objective "
        "(Craft F1@1, Dial alignment), then the other metric; *one SE*: settings within one standard "
        "error of the best objective are tied and the other metric decides (the default since "
        "docs/experiments.md §47); *best on test*: the setting with the largest F1@1 + alignment on "
        "the test episodes themselves, what a perfect choice by that sum would give. Means, F1@1 / "
        "alignment in %.",
        "",
        "| family | role | runs | picks changed | previous | one SE | Δ | best on test |",
        "|" + "---|" * 8,
        *(_line(row) for row in doc["families"]),
    ]
    return ["\n".join(lines) + "\n"]


__all__ = ["SELECTION", "selection_markdown"]
