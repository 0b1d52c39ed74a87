"""python -m lab.reproduce: the lab's in-process study of the paper's tables, through rosbag2 files.

It trains in-process and tunes its own detectors (the constrained Top-K, the online detector per run,
the duration decoder), for the ensembles, distillation, sweeps and ablations of
``results/<domain>_extras.json``.  What a user gets, ``ompn_train`` and the detector it bundles, is
measured by ``python -m lab.reproduce_product`` (``make reproduce-craft``, ``make reproduce-dial``).

Stages (each timed): collect seeded expert demonstrations into bags, read them back with the
reader users run on their own bags, hold out a test split by seed, train OMPN with the shipped
config for every setting and seed, score on the held-out episodes only (offline Top-K / automatic
threshold, the constrained Top-K, and the online causal detector through the StreamingSegmenter the
node runs), then write results/<domain>_lab.json, results/<domain>_extras.json, results/README.md and
figures.  The library is lab.

Examples:

    python -m lab.reproduce craft                       # Craft, the 4 settings, 5 seeds
    python -m lab.reproduce craft --settings full_nosketch --seeds 1 --extras none   # the <= 10 min path
    python -m lab.reproduce dial --ship
    python -m lab.reproduce --report-only               # regenerate results/README.md from the JSON
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from lab import report
from lab.pipeline import reproduce
from lab.spec import (
    ABLATIONS,
    DEFAULT_TEST_RATIO,
    EXTRAS,
    SETTINGS,
    ReproduceError,
    ReproduceSpec,
)
from ompn_ros.cli._common import make_parser, run_cli


def build_parser() -> argparse.ArgumentParser:
    p = make_parser("python -m lab.reproduce", __doc__)
    p.add_argument("domain", nargs="?", choices=sorted(SETTINGS), help="the paper's domain to reproduce")
    p.add_argument("--settings", default="", help="comma-separated subset (empty: all of the domain)")
    p.add_argument("--seeds", type=int, default=5, help="training seeds per setting (5, as the paper)")
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="demonstrations (Craft: per task, default 500; Dial: total, default 1400)",
    )
    p.add_argument("--data-seed", type=int, default=0, help="seed of the demonstration collection")
    p.add_argument(
        "--iterations", type=int, default=None,
        help="override train.iterations (none: the reproduction's fixed 200 for Craft, 300 for Dial)",
    )
    p.add_argument(
        "--test-ratio",
        type=float,
        default=DEFAULT_TEST_RATIO,
        help="fraction of each task's episodes held out for testing",
    )
    p.add_argument(
        "--config", type=Path, default=None, help="train YAML (default config/train_<domain>.yaml)"
    )
    p.add_argument(
        "--members",
        default="1",
        metavar="M | SETTING=M,...",
        help="ensemble members per seed: M for every setting, or per setting (e.g. "
        "full_nosketch=3,partial_nosketch=5; settings not named get none); 1 = single models "
        "only; with M > 1 every seed also trains M-1 members on its split and their "
        "ensemble is reported in its own table",
    )
    p.add_argument(
        "--extras",
        default="all",
        help=f"all | none | comma list of {','.join(EXTRAS)} (ensemble: the seeds' p_hat averaged, offline; "
        "distill: per seed, one OMPN that also learns its ensemble members' averaged p_hat, needs --members)",
    )
    return _add_modes(p)


def _add_modes(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Where the files go and which stages run (evaluate only, re-evaluate, skip, merge, ship)."""
    p.add_argument("--work", type=Path, default=None, help="work directory (default runs/reproduce_<domain>)")
    p.add_argument("--results", type=Path, default=Path("results"), help="directory of the result files")
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        help="override train.threads, the torch threads (none: the config's)",
    )
    p.add_argument(
        "--evaluate",
        type=Path,
        default=None,
        metavar="CHECKPOINT",
        help="skip training: evaluate this checkpoint on the held-out split of the first setting "
        "(none: train)",
    )
    p.add_argument(
        "--reevaluate",
        action="store_true",
        help="skip training: re-evaluate the existing best/ checkpoints of every setting, seed and "
        "ablation in --work (e.g. after a change to the evaluation); training figures are "
        "kept from the previous results",
    )
    p.add_argument(
        "--skip-trained",
        action="store_true",
        help="do not retrain a run whose last/ checkpoint reached train.iterations with the same "
        "model and training config (continue an interrupted reproduction, add seeds or "
        "extras to a finished one); it is evaluated as is",
    )
    p.add_argument(
        "--merge",
        action="store_true",
        help="keep the other settings already in results/<domain>_lab.json (runs split over calls)",
    )
    p.add_argument(
        "--extras-only",
        action="store_true",
        help="add extra tables to finished result files: results/<domain>_lab.json and the figures stay as "
        "they are, the tables computed now replace those of the same name, the command is listed "
        "with the later ones",
    )
    p.add_argument("--ablations", default=",".join(ABLATIONS), help="comma list for the ablation table")
    p.add_argument("--ship", action="store_true", help="copy the primary seed-0 checkpoint into the package "
                   "(with the distill extra: seed 0's distilled student)")
    p.add_argument(
        "--report-only",
        action="store_true",
        help="only regenerate RESULTS/README.md from the JSON files in --results",
    )
    return p


def _run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s: %(message)s")
    if args.report_only:
        print(f"wrote {report.write_readme(args.results)}")
        return 0
    if args.domain is None:
        raise ReproduceError("give a domain (craft or dial), or --report-only")
    spec = ReproduceSpec.build(
        args.domain,
        settings=args.settings,
        extras=args.extras,
        members=args.members,
        ablations=args.ablations,
        seeds=args.seeds,
        episodes=args.episodes,
        data_seed=args.data_seed,
        iterations=args.iterations,
        test_ratio=args.test_ratio,
        config=args.config,
        work=args.work,
        results=args.results,
        threads=args.threads,
        evaluate=args.evaluate,
        reevaluate=args.reevaluate,
        skip_trained=args.skip_trained,
        merge=args.merge,
        extras_only=args.extras_only,
        ship=args.ship,
        command=tuple(args.command_line),
    )
    return reproduce(spec)


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
