"""The memory depth × size table: ``results/craft_hparams.json`` and its ``results/README.md`` section.

The runs are those of :mod:`lab.hparams` (Craft full, no sketch, ``n`` slots × slot
size ``m``, several seeds).  ``craft_hparams.json`` (:class:`HparamsDoc`)::

    {"cells": {"n2_m128": {"n_slots", "slot_size", "paper_align", "seeds": {seed: {metric: value}},
                           "metrics": {metric: {"mean", "std", "n"}}, "stage_seconds"}},
     "meta": {"runs", "expected_runs", "seeds", "iterations", "n_test", "wall_seconds", ...}}

Metrics are fractions (seconds and iterations as they are); mean and population std over the
finite per-seed values, ``n`` = the seeds that have the metric.  ``paper_align`` is the paper's
alignment accuracy, mean and std, for the 5 cells of its table (Lu et al., ICLR 2021, Appendix
"Hyperparameter Analysis", Craft Full NoSketch), None for the others.  O(runs) to build.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypedDict

FILE = "craft_hparams.json"
FIGURE = "craft_hparams.png"
PAPER_ALIGN: dict[tuple[int, int], tuple[float, float]] = {
    (3, 64): (0.93, 0.017),
    (2, 64): (0.96, 0.014),
    (4, 64): (0.96, 0.006),
    (3, 32): (0.92, 0.042),
    (3, 128): (0.96, 0.015),
}
"""(n, m) -> the paper's alignment accuracy, mean and std (Lu et al., ICLR 2021, Appendix
"Hyperparameter Analysis", table of task alignment accuracy, Craft Full NoSketch column)."""
METRICS = (
    "align_acc",
    "f1_tol1",
    "constrained_align",
    "constrained_f1_tol1",
    "online_f1_tol1",
    "online_align",
    "online_align_strict",
    "val_align",
    "best_iteration",
    "train_seconds",
)
"""Per-seed values kept in the JSON: held-out scores (paper Top-K, constrained Top-K, online
detector), the validation alignment of the selected checkpoint, its iteration and training time."""


class Stat(TypedDict):
    mean: float | None
    std: float | None
    n: int


class PaperCell(TypedDict):
    mean: float
    std: float


class HparamsCell(TypedDict):
    n_slots: int
    slot_size: int
    paper_align: PaperCell | None
    seeds: dict[str, dict[str, float | None]]
    metrics: dict[str, Stat]
    stage_seconds: float


class HparamsDoc(TypedDict):
    cells: dict[str, HparamsCell]
    meta: dict[str, Any]


def cell_key(n_slots: int, slot_size: int) -> str:
    return f"n{n_slots}_m{slot_size}"


def stat(values: Sequence[float | None]) -> Stat:
    """Mean and population std of the finite values; None for both when there is none."""
    finite = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not finite:
        return {"mean": None, "std": None, "n": 0}
    mean = sum(finite) / len(finite)
    std = math.sqrt(sum((v - mean) ** 2 for v in finite) / len(finite))
    return {"mean": mean, "std": std, "n": len(finite)}


def _cell(rows: list[dict[str, Any]]) -> HparamsCell:
    n_slots, slot_size = int(rows[0]["n_slots"]), int(rows[0]["slot_size"])
    paper = PAPER_ALIGN.get((n_slots, slot_size))
    seeds = {
        str(r["seed"]): {k: r["row"].get(k) for k in METRICS} for r in sorted(rows, key=lambda r: r["seed"])
    }
    return {
        "n_slots": n_slots,
        "slot_size": slot_size,
        "paper_align": None if paper is None else {"mean": paper[0], "std": paper[1]},
        "seeds": seeds,
        "metrics": {k: stat([s[k] for s in seeds.values()]) for k in METRICS},
        "stage_seconds": sum(float(r["stage_seconds"]) for r in rows),
    }


def was_adopted(row: dict[str, Any]) -> bool:
    """True for a run copied from the reproduction and evaluated without training (no train time)."""
    return bool(row.get("adopted")) and row["row"].get("train_seconds") is None


def cpu_model() -> str:
    """The CPU model name of this machine (for the timing figures), or ``unknown``."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def build_doc(rows: Sequence[dict[str, Any]], expected: int, command: Sequence[str] = ()) -> HparamsDoc:
    """The JSON document from the sweep's row files (one per run), cells sorted by (n, m)."""
    grouped: dict[tuple[int, int], list[dict[str, Any]]] = {}
    for row in rows:
        grouped.setdefault((int(row["n_slots"]), int(row["slot_size"])), []).append(row)
    cells = {cell_key(*k): _cell(grouped[k]) for k in sorted(grouped)}
    meta = {
        "runs": len(rows),
        "expected_runs": expected,
        "partial": len(rows) < expected,
        "seeds": sorted({int(r["seed"]) for r in rows}),
        "iterations": sorted({int(r["iterations"]) for r in rows}),
        "n_test": sorted({int(r["n_test"]) for r in rows}),
        "adopted_runs": sorted(
            f"{cell_key(r['n_slots'], r['slot_size'])} seed {r['seed']}" for r in rows if was_adopted(r)
        ),
        "wall_seconds": max(float(r["finished"]) for r in rows) - min(float(r["started"]) for r in rows),
        "sum_stage_seconds": sum(float(r["stage_seconds"]) for r in rows),
        "cpu": cpu_model(),
        "command": list(command),
    }
    return {"cells": cells, "meta": meta}


def write_doc(results_dir: Path, doc: HparamsDoc) -> Path:
    results_dir.mkdir(parents=True, exist_ok=True)
    path = results_dir / FILE
    path.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    return path


def _pct(cell: Stat) -> str:
    if cell["mean"] is None or cell["std"] is None:
        return "–"
    return f"{100 * cell['mean']:.1f} ({100 * cell['std']:.1f})"


def _grid_lines(doc: HparamsDoc) -> list[str]:
    cells = doc["cells"].values()
    ns = sorted({c["n_slots"] for c in cells})
    ms = sorted({c["slot_size"] for c in cells})
    lines = ["| n \\ m | " + " | ".join(str(m) for m in ms) + " |", "|---|" + "---|" * len(ms)]
    for n in ns:
        row = []
        for m in ms:
            cell = doc["cells"].get(cell_key(n, m))
            if cell is None:
                row.append("–")
                continue
            paper = cell["paper_align"]
            extra = "" if paper is None else f" [{100 * paper['mean']:.0f} ({100 * paper['std']:.1f})]"
            row.append(_pct(cell["metrics"]["align_acc"]) + extra)
        lines.append(f"| {n} | " + " | ".join(row) + " |")
    return lines


def _join(values: Sequence[int]) -> str:
    return ", ".join(str(v) for v in values)


def _num(cell: Stat) -> str:
    return "–" if cell["mean"] is None else f"{cell['mean']:.0f}"


def _detail_lines(doc: HparamsDoc) -> list[str]:
    lines = [
        "| n | m | seeds | align acc | F1 tol=1 | constrained align | online F1 tol=1 | online align | "
        "val align | best iteration | train s | paper align |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cell in sorted(doc["cells"].values(), key=lambda c: (c["n_slots"], c["slot_size"])):
        met, paper = cell["metrics"], cell["paper_align"]
        paper_text = "–" if paper is None else f"{100 * paper['mean']:.0f}"
        lines.append(
            f"| {cell['n_slots']} | {cell['slot_size']} | {met['align_acc']['n']} | "
            f"{_pct(met['align_acc'])} | "
            f"{_pct(met['f1_tol1'])} | {_pct(met['constrained_align'])} | {_pct(met['online_f1_tol1'])} | "
            f"{_pct(met['online_align_strict'])} | {_pct(met['val_align'])} | "
            f"{_num(met['best_iteration'])} | {_num(met['train_seconds'])} | "
            f"{paper_text} |"
        )
    return lines


def hparams_markdown(results_dir: Path) -> list[str]:
    """The README section of ``craft_hparams.json`` (no lines when the file is absent)."""
    path = results_dir / FILE
    if not path.is_file():
        return []
    doc: HparamsDoc = json.loads(path.read_text())
    meta = doc["meta"]
    state = (
        f"partial: {meta['runs']} of {meta['expected_runs']} runs"
        if meta["partial"]
        else f"{meta['runs']} runs"
    )
    return [
        "## craft: memory depth n × slot size m (full, no sketch)",
        "",
        f"Held-out Top-K alignment accuracy, mean (std) over seeds {_join(meta['seeds'])} in %, "
        f"{_join(meta['iterations'])} iterations, {_join(meta['n_test'])} test episodes ({state}); "
        "the paper's value in brackets where its hyper-parameter table has the cell (Lu et al., ICLR 2021, "
        f"Appendix). Figure: `figures/{FIGURE}`.",
        "",
        *_grid_lines(doc),
        "",
        "Every metric per cell (online = the causal detector tuned on each run's validation episodes; "
        "val align = the selected checkpoint's validation alignment, the only number that may choose a "
        "default):",
        "",
        *_detail_lines(doc),
        "",
        f"Wall time: {meta['wall_seconds']:.0f} s for the sweep, {meta['sum_stage_seconds']:.0f} s of "
        f"training and scoring summed over runs ({meta['cpu']}).",
        "",
    ]
