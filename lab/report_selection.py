"""The "Detector selection" section of ``results/README.md``, from ``detector_selection.json``
(:mod:`lab.detector_selection`).

Metrics are fractions in the file and percentages in the table; gaps in percentage points.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .report_own import gaps, json_section, pair

SELECTION = "detector_selection.json"


def _line(row: dict[str, Any]) -> str:
    means = row["means"]
    old, new, best = (means[k] for k in ("previous", "one_se", "test_oracle"))
    bundled = means.get("bundled")  # files written before the column have none
    return (f"| {row['family']} | {row['role']} | {row['runs']} | {row['changed']} | "
            f"{pair(old['f1_1'], old['align'])} | {pair(new['f1_1'], new['align'])} | "
            f"{gaps((new['f1_1'], new['align']), (old['f1_1'], old['align']))} | "
            f"{pair(best['f1_1'], best['align'])} | "
            f"{pair(bundled['f1_1'], bundled['align']) if bundled else '–'} |")


def _intro(meta: dict[str, Any]) -> str:
    return (f"Made by `{' '.join(meta['command'])}` on {meta['date']}: the online threshold detector "
            f"each run's validation labels choose, scored on {meta['held_out']}. *previous*: the largest "
            "objective (Craft F1@1, Dial alignment), then the other metric; *one SE*: settings within "
            "one standard error of the best objective are tied and the other metric decides (the "
            "default since docs/experiments.md §47); *best on test*: the setting with the largest "
            "F1@1 + alignment on the test episodes themselves, what a perfect choice by that sum would "
            "give; *bundled*: the detector `ompn_train` bundled with the run (`detector.json`, what "
            "`ompn_node` runs from the checkpoint: Craft's duration decoder within its delay budget, "
            "Dial's threshold detector). Means, F1@1 / alignment in %.")


def selection_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The detector-selection table, when ``detector_selection.json`` exists."""
    return json_section(results_dir, SELECTION, "Detector selection: one standard error", _intro,
                        ("family", "role", "runs", "picks changed", "previous", "one SE", "Δ",
                         "best on test", "bundled"),
                        lambda doc: (_line(row) for row in doc["families"]), level)


__all__ = ["SELECTION", "selection_markdown"]
