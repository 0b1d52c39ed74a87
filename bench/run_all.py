"""Run every benchmark script in bench/, print one table, and write bench/latest.json.

Each ``bench/bench_<area>.py`` exposes ``run(quick: bool = False) -> dict[str, tuple[float, str]]``.
``bench/latest.json`` is a flat object ``{figure: {"value": v, "unit": u}}`` so that figures can be
compared across commits, plus the reserved key ``_machine`` (:data:`targets.MACHINE_KEY`): one record
per run (CPU, cores, memory, GPU, date, commit, ``--quick``) naming the areas it measured.
``--quick`` shortens the long-running figures; ``--only a,b`` selects areas.  ``bench/report.py``
then writes the table of targets at the top of BENCHMARKS.md (``make bench`` runs both).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from targets import MACHINE_KEY

HERE = Path(__file__).resolve().parent
ON_REQUEST = {"own_robot", "scale"}
"""Areas that run only when named with --only (the full own-robot flow trains for tens of minutes;
``make bench-own-robot`` runs it; ``scale`` generates and segments hundreds of bags)."""


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cpu_model() -> str:
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    names = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    return names[0] if names else (platform.processor() or platform.machine())


def _memory_gib() -> float | None:
    try:
        lines = Path("/proc/meminfo").read_text().splitlines()
    except OSError:
        return None
    kib = next((int(line.split()[1]) for line in lines if line.startswith("MemTotal:")), None)
    return None if kib is None else round(kib / 2**20, 1)


def _gpu() -> str | None:
    """The GPU torch sees, ``"none"`` without one, ``None`` when torch is missing."""
    try:
        import torch
    except ImportError:
        return None
    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"


def _commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True,
                             text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return out or None


def machine(areas: list[str], quick: bool) -> dict[str, Any]:
    """The record of this run under :data:`MACHINE_KEY`."""
    return {"areas": sorted(areas), "cpu": _cpu_model(), "cores": os.cpu_count(), "memory_gib": _memory_gib(),
            "gpu": _gpu(), "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d"),
            "commit": _commit(), "quick": quick}


def merge(old: dict[str, Any], new: dict[str, Any], only: set[str]) -> dict[str, Any]:
    """``new`` figures and machine over ``old``: a subset run (``only``) keeps the other areas' figures
    and the records of the runs that measured them; a full run replaces everything."""
    if not only:
        return new
    kept = {k: v for k, v in old.items() if k != MACHINE_KEY and k.split(".", 1)[0] not in only}
    runs = [{**r, "areas": [a for a in r["areas"] if a not in only]} for r in old.get(MACHINE_KEY, [])]
    return {**kept, **new, MACHINE_KEY: [*(r for r in runs if r["areas"]), *new[MACHINE_KEY]]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (less precise figures)")
    parser.add_argument("--only", default="", help="comma-separated areas, e.g. model,craft (the other "
                        "areas' figures in --out are kept)")
    parser.add_argument("--out", type=Path, default=HERE / "latest.json")
    args = parser.parse_args(argv)
    only = {a for a in args.only.split(",") if a}
    figures: dict[str, Any] = {}
    failures, measured = [], []
    for path in sorted(HERE.glob("bench_*.py")):
        area = path.stem.removeprefix("bench_")
        if (only and area not in only) or (not only and area in ON_REQUEST):
            continue
        start = time.perf_counter()
        print(f"== {area} ...", flush=True)
        try:
            results = _load(path).run(quick=args.quick)
        except Exception:  # one broken benchmark must not hide the others
            traceback.print_exc()
            failures.append(area)
            continue
        for name, (value, unit) in results.items():
            figures[f"{area}.{name}"] = {"value": value, "unit": unit}
        measured.append(area)
        print(f"   done in {time.perf_counter() - start:.1f} s", flush=True)
    width = max((len(k) for k in figures), default=10)
    print(f"\n{'figure':<{width}}  {'value':>14}  unit")
    for name, fig in figures.items():
        value = fig["value"]
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        print(f"{name:<{width}}  {shown:>14}  {fig['unit']}")
    figures[MACHINE_KEY] = [machine(measured, args.quick)]
    if only and args.out.is_file():  # a subset run keeps the other areas' figures of the last full run
        figures = merge(json.loads(args.out.read_text()), figures, only)
    args.out.write_text(json.dumps(figures, indent=1, sort_keys=True) + "\n")
    print(f"\nwrote {args.out}")
    if failures:
        print(f"FAILED benchmarks: {', '.join(failures)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
