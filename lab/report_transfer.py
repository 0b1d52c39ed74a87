"""The "Transfer" section of ``results/README.md``, from ``transfer.json`` (:mod:`lab.transfer`).

Metrics are fractions in the file and percentages in the table; gaps in percentage points.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .report_own import gaps, json_section, pair

TRANSFER = "transfer.json"
WARMUP = "agreement_warmup.json"
"""The label-free warm-up check (:mod:`lab.warmup_check`), one source of the transfer table."""
BUDGET = "delay_budget.json"
"""The decoder's delay budget check (:mod:`lab.budget_check`), one source of the transfer table."""


def _seeds(seeds: list[int]) -> str:
    contiguous = seeds == list(range(seeds[0], seeds[-1] + 1))
    return f"{seeds[0]}–{seeds[-1]}" if contiguous and len(seeds) > 2 else ", ".join(map(str, seeds))


def _line(row: dict[str, Any]) -> str:
    mine, ref = row["with_default"], row["without"]
    figures = [(mine[f"{k}_f1_1"], mine[f"{k}_align"]) for k in ("offline", "online")]
    refs = [(ref[f"{k}_f1_1"], ref[f"{k}_align"]) for k in ("offline", "online")]
    verdict = "holds" if row["holds"] else "loses more than 2 points"
    earlier = row.get("earlier_restart_rule", 0)
    runs = f"{earlier} run" + ("s" if earlier > 1 else "")
    family = row["family"] + (f" ({runs} under the earlier restart rule)" if earlier else "")
    return (f"| {row['default']} | {row['tuned_on']} | {family} | {row['kept_out_of_tuning']} | "
            f"{_seeds(row['seeds'])} | {row['reference']} | {pair(*figures[0])} | "
            f"{gaps(figures[0], refs[0])} | {pair(*figures[1])} | {gaps(figures[1], refs[1])} | {verdict} |")


def _intro(meta: dict[str, Any]) -> str:
    return (f"Made by `{' '.join(meta['command'])}` on {meta['date']} from `{meta['source']}`: means "
            f"over the seeds, {meta['held_out']}. F1@1 / alignment in %; Δ = with the default (or on the "
            f"family) minus the reference, in points. A default holds when no figure loses more than "
            f"{meta['tolerance_points']:g} points."
            + (f" Detector: {meta['detector']}." if "detector" in meta else ""))


def transfer_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The transfer table, when ``transfer.json`` exists."""
    columns = ("default", "tuned on", "family", "kept out of tuning", "seeds", "reference", "offline",
               "Δ offline", "online", "Δ online", "verdict")
    return json_section(results_dir, TRANSFER, "Transfer: tuned defaults on data they were not tuned on",
                        _intro, columns, lambda doc: (_line(row) for row in doc["rows"]), level)


__all__ = ["BUDGET", "TRANSFER", "WARMUP", "transfer_markdown"]
