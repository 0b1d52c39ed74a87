"""The "final_observation: auto" section of ``results/README.md``, from ``final_auto.json``
(:mod:`lab.final_auto`).

Metrics are fractions in the file and percentages in the table.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .report_own import json_section, pair

FINAL_AUTO = "final_auto.json"


def _lines(family: dict[str, Any]) -> list[str]:
    """Rows auto, each option alone (with how often validation kept it) and complete bags."""
    means, kept, n = family["means"], family["kept"], len(family["seeds"])
    label = f"{family['family']} (seeds {family['seeds'][0]}–{family['seeds'][-1]}; {family['role']})"
    rows = [("auto", "auto", "–"), *((o, f"{o} alone", f"{k} of {n}") for o, k in kept.items()),
            ("complete", "complete bags", "–")]
    out = []
    for i, (key, name, count) in enumerate(rows):
        m = means[key]
        offline = pair(m["offline_f1_1"], m["offline_align"])
        online = pair(m["online_f1_1"], m["online_align"])
        out.append(f"| {label if i == 0 else ''} | {name} | {count} | {offline} | {online} |")
    return out


def _intro(meta: dict[str, Any]) -> str:
    return (f"Made by `{' '.join(meta['command'])}` on {meta['date']}: per seed, the runs trained on bags "
            "without the observation after the last command, row T read as `extrapolate` and as "
            "`duplicate` on the same split; *auto* keeps the one whose online detector validation prefers "
            "(best alignment within one standard error, then F1@1), as `ompn_train` does. Scored on "
            f"{meta['held_out']}; {meta['detector']}. Means, F1@1 / alignment in %.")


def final_auto_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The table of ``final_observation: auto``, when ``final_auto.json`` exists."""
    return json_section(results_dir, FINAL_AUTO, "final_observation: auto on Dial", _intro,
                        ("family", "runs", "kept by validation", "offline", "online"),
                        lambda doc: (line for family in doc["families"] for line in _lines(family)), level)


__all__ = ["FINAL_AUTO", "final_auto_markdown"]
