"""ompn_collect: expert or human-like demonstrations -> rosbag2 parts, without DDS.

Example:

    ompn_collect --domain craft --task makebed,makeaxe --episodes 200 --seed 0 --out bags/craft \\
        --split-every 50

writes bags/craft/part_000/ ... part_003/ (one rosbag2 v9 directory per part; a single part_000
without --split-every) and bags/craft/collect.json (command, seeds, counts).  Episode i uses task
tasks[i % len(tasks)] and seed episode_seed(seed, i).  Each part is written under a hidden
temporary name and renamed when complete, so --resume continues after the last complete part and
never reads a half-written one.  The library is ompn_ros.app.collect.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from ompn_ros.app.collect import DEMONSTRATORS, DOMAINS, STORAGES, collect, default_generator, human_settings
from ompn_ros.app.errors import CollectError
from ompn_ros.cli._common import make_parser, run_cli

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = make_parser("ompn_collect", __doc__.split("\n\n")[0])
    parser.add_argument(
        "--domain", required=True, choices=sorted(DOMAINS), help="which simulator's expert"
    )
    parser.add_argument(
        "--task",
        default=None,
        help="comma-separated task names (craft: e.g. makebed,makeaxe, required; dial: none needed)",
    )
    parser.add_argument("--episodes", type=int, required=True, help="number of demonstrations")
    parser.add_argument("--seed", type=int, default=0, help="run seed; episode i uses episode_seed(seed, i)")
    parser.add_argument("--out", required=True, type=Path, help="output directory of the bag parts")
    parser.add_argument("--storage", choices=STORAGES, default="mcap", help="rosbag2 storage plugin format")
    parser.add_argument(
        "--split-every",
        type=int,
        default=None,
        metavar="M",
        help="write a new bag part every M episodes (none: one part)",
    )
    parser.add_argument(
        "--partial",
        action="store_true",
        help="craft: partial (egocentric) observations instead of the full grid",
    )
    parser.add_argument(
        "--demonstrator",
        choices=DEMONSTRATORS,
        default="expert",
        help="the scripted expert, or the human-like demonstrator (pauses, tempo, overshoots, wrong moves "
        "undone, sensor noise, dropped and duplicated observation messages)",
    )
    parser.add_argument(
        "--human",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a human-like parameter, repeatable, e.g. pause_rate=0.05 or pause_steps=2:8 (without it: the "
        "domain's defaults, docs/craft.md §2.6, docs/dial.md §3.9)",
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="continue after the last complete part")
    mode.add_argument("--overwrite", action="store_true", help="replace an existing output")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _run(args: argparse.Namespace) -> int:
    if args.task:
        tasks = [t.strip() for t in args.task.split(",") if t.strip()]
    elif args.domain == "dial":
        tasks = ["dial"]
    else:
        raise CollectError("--task is required for craft")
    if args.human and args.demonstrator != "human":
        raise CollectError("--human sets human-like parameters: add --demonstrator human")
    human = human_settings(args.domain, args.human) if args.demonstrator == "human" else None
    # looked up here, so a test can replace this module's default_generator
    manifest = collect(
        args.out,
        domain=args.domain,
        tasks=tasks,
        episodes=args.episodes,
        seed=args.seed,
        storage=args.storage,
        split_every=args.split_every,
        partial=args.partial,
        resume=args.resume,
        overwrite=args.overwrite,
        progress=not args.quiet,
        generator=default_generator(args.domain, human),
        human=human,
        command=args.command_line,
    )
    t = manifest["totals"]
    print(
        f"wrote {t['episodes']} episodes ({t['steps']} steps, {t['successes']} successful, "
        f"{t['messages']} messages) in {t['parts']} part(s) under {args.out}"
    )
    if human is not None:
        dropped = sum(p.get("dropped_observations", 0) for p in manifest["parts"])
        doubled = sum(p.get("duplicated_observations", 0) for p in manifest["parts"])
        how = ("the presets read them (duplicates are read once)" if not dropped else
               "read the bags with 'strict: false' in the reader spec (a dropped observation's step "
               "is lost)")
        print(f"human-like: {dropped} observation messages dropped, {doubled} duplicated; {how} "
              "(docs/dial.md §3.9)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (2 on a usage/output problem)."""
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
