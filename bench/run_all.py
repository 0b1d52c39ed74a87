"""Run every benchmark script in bench/, print one table, and write bench/latest.json.

Each ``bench/bench_<area>.py`` exposes ``run(quick: bool = False) -> dict[str, tuple[float, str]]``.
``bench/latest.json`` is a flat object ``{figure: {"value": v, "unit": u}}`` so that figures can be
compared across commits.  ``--quick`` shortens the long-running figures; ``--only a,b`` selects areas.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
import traceback
from pathlib import Path

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (less precise figures)")
    parser.add_argument("--only", default="", help="comma-separated areas, e.g. model,craft (the other "
                        "areas' figures in --out are kept)")
    parser.add_argument("--out", type=Path, default=HERE / "latest.json")
    args = parser.parse_args(argv)
    only = {a for a in args.only.split(",") if a}
    figures: dict[str, dict[str, object]] = {}
    failures = []
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
        print(f"   done in {time.perf_counter() - start:.1f} s", flush=True)
    width = max((len(k) for k in figures), default=10)
    print(f"\n{'figure':<{width}}  {'value':>14}  unit")
    for name, fig in figures.items():
        value = fig["value"]
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        print(f"{name:<{width}}  {shown:>14}  {fig['unit']}")
    if only and args.out.is_file():  # a subset run keeps the other areas' figures of the last full run
        kept = {k: v for k, v in json.loads(args.out.read_text()).items() if k.split(".", 1)[0] not in only}
        figures = {**kept, **figures}
    args.out.write_text(json.dumps(figures, indent=1, sort_keys=True) + "\n")
    print(f"\nwrote {args.out}")
    if failures:
        print(f"FAILED benchmarks: {', '.join(failures)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
