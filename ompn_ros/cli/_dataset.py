"""``ompn_segment --dataset DIR``: segment a LeRobot dataset and write its subtasks back.

The options and the command-line shell; the work is ``app/lerobot_segment.py`` (the run) and
``app/lerobot_write.py`` (the formats, the shared copy, the in-place rewrite).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ompn_ros.app.errors import ReplayError
from ompn_ros.app.lerobot_write import ALIASES, BOUNDARIES, FORMATS


def add_dataset_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--dataset", metavar="DIR",
        help="a LeRobot v3 dataset (local folder): every episode is segmented into OUT/segments.csv and "
        "OUT/summary.json (none: a bag)")
    parser.add_argument(
        "--dataset-spec", metavar="YAML",
        help="with --dataset: which features are the observation, the action, the labels "
        "(config/dataset_example.yaml; none: observation.state, action, no labels)")
    parser.add_argument(
        "--write-subtasks", metavar="FORMAT", choices=sorted([*ALIASES, *FORMATS]),
        help="with --dataset: write the subtasks back in a LeRobot format: index (per-frame subtask_index "
        "+ meta/subtasks.parquet), language (language_persistent rows, style subtask), episodes (per-episode "
        "start/end frames in meta/episodes); -v1 names the version; into --annotate DIR (default "
        "OUT/dataset, sharing the unchanged files) or --in-place (none: the table only)")
    parser.add_argument("--in-place", action="store_true",
                        help="with --write-subtasks: rewrite the dataset's own files that change, atomically")
    parser.add_argument(
        "--boundaries", choices=BOUNDARIES, default="online",
        help="with --dataset: what the node publishes (online), or the offline Top-K of the same replay")
    parser.add_argument("--subtasks", type=int, metavar="K",
                        help="with --boundaries top_k: subtasks per episode (none: the episode's labels)")


def _check(args: argparse.Namespace) -> None:
    if args.bag or args.bags or args.tune or args.generate:
        raise ReplayError("--dataset segments a dataset: give it without --bag, --bags, --tune and "
                          "--generate")
    if args.in_place and not args.write_subtasks:
        raise ReplayError("--in-place rewrites the dataset with --write-subtasks FORMAT: give the format")
    if args.in_place and args.annotate:
        raise ReplayError("--in-place writes into the dataset itself: give it without --annotate")
    if args.subtasks is not None and (args.boundaries != "top_k" or args.subtasks < 1):
        raise ReplayError("--subtasks K (K >= 1) goes with --boundaries top_k")
    if args.num_shards is not None or args.shard_index is not None:
        from ompn_ros.app import shards

        shards.check_shard(args.num_shards, args.shard_index)
        if args.in_place or args.annotate:
            raise ReplayError("a shard writes no dataset: give --num-shards without --in-place and "
                              "--annotate; ompn_segment aggregate writes the annotated dataset "
                              "(its --annotate DIR)")


def run_dataset_cli(args: argparse.Namespace, device: str = "cpu") -> int:
    """Segment ``--dataset`` (see the module doc); 0 when done."""
    from ompn_ros.app.lerobot_segment import DatasetRun, dataset_spec, segment_dataset
    from ompn_ros.app.segment_setup import detector_settings, load_stepper

    _check(args)
    spec = dataset_spec(args.dataset_spec)
    load_stepper(args.checkpoint, device)  # a bad checkpoint is one line before anything is written
    detector, line = detector_settings(args.checkpoint, args.detector_config)
    print(f"ompn_segment: {line}", file=sys.stderr)
    run = DatasetRun(
        checkpoint=args.checkpoint, detector=detector.online, duration_model=detector.duration_model,
        head=detector.head, out=Path(args.out), spec=spec, boundaries=args.boundaries, subtasks=args.subtasks,
        fmt=args.write_subtasks, annotate=Path(args.annotate) if args.annotate else None,
        in_place=args.in_place, overwrite=args.overwrite, device=device)
    def progress(text: str) -> None:
        print(f"ompn_segment: {text}", file=sys.stderr, flush=True)

    if args.num_shards is not None:
        from ompn_ros.app.lerobot_shards import run_shard

        summary = run_shard(run, args.dataset, args.num_shards, args.shard_index, progress)
    else:
        summary = segment_dataset(run, args.dataset, progress)
    for note in summary["notes"]:
        print(f"ompn_segment: {note}", file=sys.stderr)
    print(json.dumps(summary, indent=1))
    return 0
