"""What keeping the best of N runs by validation would have scored, from runs already trained.

For a set of seeds and a size ``N``, every ``N``-subset of the seeds is taken.  Within a subset, the
run with the highest best validation criterion (the maximum of ``align`` in its ``log.jsonl``, what
``train.selection: align`` keeps) stands for the subset; its held-out scores (``arms/<arm>.json``) are
averaged over all subsets.  That is the expected score of ``train.candidates: N`` when candidates are
drawn like these seeds (docs/experiments.md §43).  Only validation decides which run is kept; the
test scores are read afterwards.

Cost: ``C(len(seeds), N)`` subsets of O(N) each, after reading one log per run.

    python -m lab.subsets --work runs/own_data --arm final_craft_full_blank \\
        --against final_craft_full_complete --seeds 0-9 --n 1 2 3
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ompn_ros.errors import OMPNError

FIGURES = ("online_f1_1", "online_align", "offline_f1_1", "offline_align")
CRITERION = "align"


class SubsetError(OMPNError, ValueError):
    """A run or arm file is missing or holds no validation criterion; the message names it."""


@dataclass(frozen=True)
class Run:
    """One trained seed: its best validation criterion and its held-out figures."""

    seed: int
    best_val: float
    figures: dict[str, float]


def arm_name(prefix: str, seed: int) -> str:
    """The own-data arm of ``prefix`` for ``seed`` (seed 0 has no suffix)."""
    return prefix if seed == 0 else f"{prefix}_seed{seed}"


def read_run(work: Path, prefix: str, seed: int) -> Run:
    """The run of ``prefix`` and ``seed`` under ``work`` (``runs/<arm>/log.jsonl``, ``arms/<arm>.json``)."""
    arm = arm_name(prefix, seed)
    log, row = work / "runs" / arm / "log.jsonl", work / "arms" / f"{arm}.json"
    try:
        records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
        doc = json.loads(row.read_text())
    except (OSError, ValueError) as exc:
        raise SubsetError(f"{arm}: cannot read its log or arm file ({exc})") from exc
    values = [float(r[CRITERION]) for r in records if CRITERION in r]
    if not values:
        raise SubsetError(f"{log}: no validation '{CRITERION}' logged")
    try:
        figures = {k: float(doc[k]) for k in FIGURES}
    except (KeyError, TypeError, ValueError) as exc:
        raise SubsetError(f"{row}: missing held-out figure {exc}") from exc
    return Run(seed, max(values), figures)


def best_of(runs: Sequence[Run], n: int) -> dict[str, float]:
    """Mean held-out figures of the validation-best run over every ``n``-subset of ``runs`` (ties: the
    lower seed, as the trainer keeps its first candidate)."""
    if not 1 <= n <= len(runs):
        raise SubsetError(f"N={n} needs 1 <= N <= {len(runs)} runs")
    totals = dict.fromkeys(FIGURES, 0.0)
    subsets = list(itertools.combinations(runs, n))
    for subset in subsets:
        kept = max(subset, key=lambda r: (r.best_val, -r.seed))
        for k in FIGURES:
            totals[k] += kept.figures[k]
    return {k: v / len(subsets) for k, v in totals.items()}


def seeds_arg(text: str) -> list[int]:
    """``"0-9"`` or ``"0,2,5"``."""
    if "-" in text:
        first, last = text.split("-", 1)
        return list(range(int(first), int(last) + 1))
    return [int(s) for s in text.split(",")]


def table(work: Path, arm: str, against: str, seeds: list[int], sizes: list[int]) -> list[str]:
    """Markdown rows: per N, both prefixes' expected figures and the gap (percentage points)."""
    ours = [read_run(work, arm, s) for s in seeds]
    theirs = [read_run(work, against, s) for s in seeds]
    lines = [f"| N | {arm} online F1@1 / align | offline | {against} online | offline | gap online | "
             "gap offline |", "|---|---|---|---|---|---|---|"]
    for n in sizes:
        a, b = best_of(ours, n), best_of(theirs, n)
        cell = [f"{100 * x[f'{k}_f1_1']:.1f} / {100 * x[f'{k}_align']:.1f}" for x in (a, b)
                for k in ("online", "offline")]
        gap = [" / ".join(f"{100 * (a[f'{k}_{m}'] - b[f'{k}_{m}']):+.1f}" for m in ("f1_1", "align"))
               for k in ("online", "offline")]
        lines.append(f"| {n} | {' | '.join(cell)} | {' | '.join(gap)} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Print the best-of-N table; exit 2 on a missing run."""
    parser = argparse.ArgumentParser(prog="python -m lab.subsets",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/own_data"))
    parser.add_argument("--arm", required=True, help="arm prefix, e.g. final_craft_full_blank")
    parser.add_argument("--against", required=True, help="the prefix compared with, same seeds")
    parser.add_argument("--seeds", type=seeds_arg, default=seeds_arg("0-9"), help="'0-9' or '0,2,5'")
    parser.add_argument("--n", type=int, nargs="+", default=[1, 2, 3], help="subset sizes")
    args = parser.parse_args(argv)
    try:
        print("\n".join(table(args.work, args.arm, args.against, args.seeds, args.n)))
    except SubsetError as exc:
        print(f"subsets: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
