"""The memory depth × size sweep on Craft full without a sketch (Lu et al., ICLR 2021, Appendix
"Hyperparameter Analysis"): ``n`` memory slots × slot size ``m``, a few seeds per cell, each run
trained and scored like the reproduction's runs (fixed length, the same held-out test split; the
paper's Top-K, the constrained Top-K and the online detector, see :mod:`lab.scoring`).

Resumable and shardable: a finished run leaves ``<work>/runs/<run>/hparams_row.json`` and is skipped
by the next call, so a killed sweep continues where it stopped, and ``--shard I/N`` processes share
the grid (start the second after the first has read the bags: they share the episode cache).
``--report`` builds ``results/craft_hparams.json``, its figure and ``results/README.md`` from the
row files (:mod:`lab.report_hparams`)::

    python -m lab.hparams --work runs/hparams --threads 1 --shard 0/2
    python -m lab.hparams --work runs/hparams --threads 1 --shard 1/2
    python -m lab.hparams --work runs/hparams --report

Cost: ``|n| · |m| · seeds`` trainings of ``iterations`` updates, plus one held-out evaluation each.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab import report, report_hparams
from lab.hparams_figure import save_hparams_figure
from lab.pipeline import State, prepare
from lab.runs import run_setting
from lab.spec import SETTINGS, ReproduceError, ReproduceSpec, RunSpec
from ompn_ros.cli._common import make_parser, run_cli

SETTING = "full_nosketch"
ROW_FILE = "hparams_row.json"
DEFAULT_N = (2, 3, 4)
DEFAULT_M = (32, 64, 128)
DEFAULT_SEEDS = (0, 1, 2)


@dataclass(frozen=True)
class Cell:
    """One run of the grid: ``n_slots`` × ``slot_size`` at one training seed."""

    n_slots: int
    slot_size: int
    seed: int

    @property
    def key(self) -> str:
        return report_hparams.cell_key(self.n_slots, self.slot_size)

    def run_spec(self, iterations: int | None) -> RunSpec:
        """The reproduction's run of :data:`SETTING` with this cell's memory overrides."""
        return RunSpec(
            domain="craft",
            setting=SETTINGS["craft"][SETTING],
            seed=self.seed,
            iterations=iterations,
            overrides={"n_slots": self.n_slots, "slot_size": self.slot_size},
            tag=f"_n{self.n_slots}_m{self.slot_size}",
            skip_trained=True,
        )


@dataclass(frozen=True)
class SweepSpec:
    """What one call of the sweep does, validated before any stage runs."""

    work: Path
    results: Path = Path("results")
    n_slots: tuple[int, ...] = DEFAULT_N
    slot_sizes: tuple[int, ...] = DEFAULT_M
    seeds: tuple[int, ...] = DEFAULT_SEEDS
    shard: tuple[int, int] = (0, 1)
    iterations: int | None = None
    episodes: int = 0
    threads: int | None = None
    reuse_runs: Path | None = None
    command: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for what, values in (("--n", self.n_slots), ("--m", self.slot_sizes)):
            if not values or min(values) < 1:
                raise ReproduceError(f"{what} must list positive integers, got {list(values)}")
        if not self.seeds or min(self.seeds) < 0:
            raise ReproduceError(f"--seeds must list integers >= 0, got {list(self.seeds)}")
        index, count = self.shard
        if count < 1 or not 0 <= index < count:
            raise ReproduceError(f"--shard must be I/N with 0 <= I < N, got {index}/{count}")

    def cells(self) -> list[Cell]:
        """Every run of the grid, n-major then m then seed; this process's shard only."""
        grid = [Cell(n, m, s) for n in self.n_slots for m in self.slot_sizes for s in self.seeds]
        index, count = self.shard
        return [c for i, c in enumerate(grid) if i % count == index]


def _finite(value: Any) -> Any:
    """JSON has no NaN: non-finite floats are written as null."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def finished_row(run_dir: Path, cell: Cell, iterations: int) -> dict[str, Any] | None:
    """The row file of ``run_dir`` when it is of ``cell`` at ``iterations``, else None."""
    path = run_dir / ROW_FILE
    try:
        doc: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    same = (doc.get("n_slots"), doc.get("slot_size"), doc.get("seed"), doc.get("iterations"))
    return doc if same == (cell.n_slots, cell.slot_size, cell.seed, iterations) else None


def validation_align(run_dir: Path) -> float | None:
    """Top-K alignment on the run's validation episodes at its best checkpoint (never test data)."""
    try:
        meta = json.loads((run_dir / "best" / "meta.json").read_text())
    except (OSError, ValueError):
        return None
    value = meta.get("extra", {}).get("metrics", {}).get("topk_align")
    return float(value) if isinstance(value, (int, float)) else None


def adopt_reproduction_run(source: Path, run_dir: Path) -> bool:
    """Copy a finished reproduction run (``best/``, ``last/``, ``log.jsonl``) into ``run_dir``.

    The copy is evaluated, not retrained, only when its stored model and training configuration
    equal the cell's (:func:`lab.runs.trained_to_the_end`); otherwise it is
    trained again like any other run."""
    if run_dir.exists() or not (source / "best").is_dir() or not (source / "last").is_dir():
        return False
    run_dir.mkdir(parents=True)
    for name in ("best", "last"):
        shutil.copytree(source / name, run_dir / name)
    if (source / "log.jsonl").is_file():
        shutil.copy2(source / "log.jsonl", run_dir / "log.jsonl")
    (run_dir / "adopted_from.txt").write_text(f"{source}\n")
    return True


def run_cell(state: State, sweep: SweepSpec, cell: Cell) -> dict[str, Any]:
    """Train (or reuse) and score one cell's run; write and return its row file."""
    run_spec = cell.run_spec(sweep.iterations)
    run_dir = sweep.work / "runs" / run_spec.name
    iterations = int(state.base["train"]["iterations"] if sweep.iterations is None else sweep.iterations)
    done = finished_row(run_dir, cell, iterations)
    if done is not None:
        print(f"   {run_spec.name}: scored already, skipped", flush=True)
        return done
    shipped = (cell.n_slots, cell.slot_size) == (
        state.base["model"]["n_slots"],
        state.base["model"]["slot_size"],
    )
    adopted = False
    if shipped and sweep.reuse_runs is not None:
        adopted = adopt_reproduction_run(sweep.reuse_runs / f"{SETTING}_seed{cell.seed}", run_dir)
    pool, test = state.split_of(SETTING)
    started = time.time()
    run = state.timer.run(
        f"train+eval n={cell.n_slots} m={cell.slot_size} seed {cell.seed}",
        run_setting,
        run_spec,
        pool,
        test,
        state.base,
        sweep.work,
    )
    finished = time.time()
    row = {k: _finite(v) for k, v in run.row.items()}
    row["val_align"] = validation_align(run_dir)
    doc = {
        "n_slots": cell.n_slots,
        "slot_size": cell.slot_size,
        "seed": cell.seed,
        "iterations": iterations,
        # a copy finished with another configuration was trained again: it is no adopted run
        "adopted": adopted and row.get("train_seconds") is None,
        "n_test": len(test),
        "started": started,
        "finished": finished,
        "stage_seconds": finished - started,
        "row": row,
    }
    (run_dir / ROW_FILE).write_text(json.dumps(doc, indent=1) + "\n")
    print("   " + ", ".join(f"{k} {row[k]:.3f}" for k in ("align_acc", "f1_tol1") if row.get(k) is not None))
    return doc


def reproduce_spec(sweep: SweepSpec) -> ReproduceSpec:
    """The reproduction's data and training setup for the sweep (Craft, full observations)."""
    return ReproduceSpec.build(
        "craft",
        settings=SETTING,
        extras="none",
        seeds=max(sweep.seeds) + 1,
        episodes=sweep.episodes,
        iterations=sweep.iterations,
        work=sweep.work,
        results=sweep.results,
        threads=sweep.threads,
        command=sweep.command,
    )


def run_sweep(sweep: SweepSpec) -> int:
    """Every cell of this shard, skipping the scored ones; returns the exit code."""
    state = prepare(reproduce_spec(sweep))
    cells = sweep.cells()
    print(f"   {len(cells)} runs in shard {sweep.shard[0]}/{sweep.shard[1]}", flush=True)
    for cell in cells:
        run_cell(state, sweep, cell)
    print(f"shard done in {time.perf_counter() - state.timer.start:.1f} s", flush=True)
    return 0


def collect_rows(sweep: SweepSpec) -> list[dict[str, Any]]:
    """The row files of the whole grid (every shard) that exist in ``sweep.work``."""
    everything = SweepSpec(sweep.work, n_slots=sweep.n_slots, slot_sizes=sweep.slot_sizes, seeds=sweep.seeds)
    rows = []
    for cell in everything.cells():
        run_dir = sweep.work / "runs" / cell.run_spec(sweep.iterations).name
        path = run_dir / ROW_FILE
        if path.is_file():
            rows.append(json.loads(path.read_text()))
    return rows


def write_report(sweep: SweepSpec) -> int:
    """``--report``: the JSON, the figure and ``README.md`` from the row files found."""
    rows = collect_rows(sweep)
    if not rows:
        raise ReproduceError(f"report: no scored runs ({ROW_FILE}) under {sweep.work / 'runs'}")
    expected = len(sweep.n_slots) * len(sweep.slot_sizes) * len(sweep.seeds)
    doc = report_hparams.build_doc(rows, expected=expected, command=list(sweep.command))
    path = report_hparams.write_doc(sweep.results, doc)
    figure = save_hparams_figure(doc, sweep.results / "figures" / report_hparams.FIGURE)
    print(f"wrote {path} ({len(rows)} of {expected} runs), {figure}, {report.write_readme(sweep.results)}")
    return 0


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ReproduceError(f"expected a comma list of integers, got {text!r}") from None


def _shard(text: str) -> tuple[int, int]:
    index, _, count = text.partition("/")
    try:
        return int(index), int(count)
    except ValueError:
        raise ReproduceError(f"--shard must be I/N (e.g. 0/2), got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    p = make_parser("python -m lab.hparams", __doc__)
    p.add_argument("--work", type=Path, default=Path("runs") / "hparams", help="work directory")
    p.add_argument("--results", type=Path, default=Path("results"), help="directory of the result files")
    p.add_argument("--n", default="2,3,4", help="memory slots n (comma list)")
    p.add_argument("--m", default="32,64,128", help="slot sizes m (comma list)")
    p.add_argument("--seeds", default="0,1,2", help="training seeds (comma list)")
    p.add_argument("--shard", default="0/1", help="I/N: run every N-th run of the grid from the I-th")
    p.add_argument(
        "--iterations", type=int, default=None, help="training length (none: the reproduction's fixed 200)"
    )
    p.add_argument("--episodes", type=int, default=None, help="demonstrations per task (default 500)")
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch threads per training (none: the config's train.threads)",
    )
    p.add_argument(
        "--reuse-runs",
        type=Path,
        default=None,
        metavar="RUNS_DIR",
        help="a reproduction's runs/ directory: its full_nosketch_seed<s> runs serve as the shipped "
        "config's cell when their stored configuration matches (none: train that cell too)",
    )
    p.add_argument("--report", action="store_true", help="only write the result files from the scored runs")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body(args: argparse.Namespace) -> int:
        sweep = SweepSpec(
            work=args.work,
            results=args.results,
            n_slots=_ints(args.n),
            slot_sizes=_ints(args.m),
            seeds=_ints(args.seeds),
            shard=_shard(args.shard),
            iterations=args.iterations,
            episodes=args.episodes or 0,
            threads=args.threads,
            reuse_runs=args.reuse_runs,
            command=tuple(args.command_line),
        )
        return write_report(sweep) if args.report else run_sweep(sweep)

    return run_cli(build_parser(), body, argv)


if __name__ == "__main__":
    sys.exit(main())
