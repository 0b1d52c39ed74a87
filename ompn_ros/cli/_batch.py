"""``ompn_segment --bags SOURCE --jobs N``: segment many bags over a pool of processes.

The options and the command-line shell of batch mode, its shards and ``ompn_segment aggregate``;
the work is ``app/batch.py`` (tasks, resuming), ``app/batch_pool.py`` (workers, stopping),
``app/shards.py`` (assignment, merge) and ``app/batch_table.py`` (table, summary, metrics).

SIGINT (Ctrl-C) or SIGTERM stops a run after the bags in progress: the table and summary of what
finished are written and the command exits ``128 + signal`` (130, 143); a rerun finishes the rest.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ompn_ros.app.errors import ReplayError
from ompn_ros.app.segment_setup import detector_settings
from ompn_ros.cli._common import make_parser

if TYPE_CHECKING:  # the batch services load when a batch runs, not for --help
    from ompn_ros.app.batch import BatchSettings
    from ompn_ros.app.batch_bags import BatchBag

SOME_REFUSED = 1
"""Exit status of a batch run in which some bags were refused (2: the run itself could not start)."""


def add_batch_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bags", metavar="SOURCE",
        help="batch mode: a folder of bags, a glob, or a text file listing one bag per line; every bag is "
        "segmented into OUT/segments.csv, OUT/summary.json, OUT/metrics.json (labels) and "
        "OUT/bags/<key>.json; a rerun skips complete bags (none: one --bag)")
    parser.add_argument("--jobs", type=int, default=1, help="batch mode: worker processes, one bag per task")
    parser.add_argument(
        "--num-shards", type=int, metavar="N",
        help="--bags or --dataset: split the bags (by a hash of each bag's key) or the episodes "
        "(episode_index mod N) into N shards and run only shard --shard-index (one machine or array task "
        "each; then ompn_segment aggregate OUT...; none: all of them)")
    parser.add_argument("--shard-index", type=int, metavar="I",
                        help="with --num-shards: the shard to run, 0..N-1 (none: all bags or episodes)")


def check_batch_arguments(args: argparse.Namespace) -> None:
    """Refuse option combinations batch mode does not take (one line naming the option)."""
    if args.bags and (args.bag or args.tune or args.generate):
        raise ReplayError("--bags replays many bags: give it without --bag, --tune and --generate")
    if args.jobs < 1:
        raise ReplayError(f"--jobs must be at least 1, got {args.jobs}")
    if args.num_shards is not None and not args.bags:
        raise ReplayError("--num-shards splits the bags of --bags or the episodes of --dataset: give one")
    from ompn_ros.app import shards

    shards.check_shard(args.num_shards, args.shard_index)


def _check_copies(annotate: Path | None, bags: list[BatchBag]) -> None:
    """Refuse annotated copies among the bags to segment (a rerun would segment the copies)."""
    if annotate is None:
        return
    folder = annotate.resolve()
    inside = [b.path for b in bags if b.path is not None and folder in b.path.resolve().parents]
    if inside:
        raise ReplayError(f"--annotate {annotate} holds bags that --bags lists ({inside[0]}): a rerun would "
                         "segment the copies; write them elsewhere")


def run_batch_cli(args: argparse.Namespace, device: str = "cpu") -> int:
    """Segment the bags of ``--bags`` (or of one shard of them) on ``device`` ('cpu' or 'cuda'); 0 when
    every bag was segmented, :data:`SOME_REFUSED` otherwise, ``128 + signal`` when stopped."""
    from ompn_ros.app import batch_table, shards
    from ompn_ros.app.batch import BatchSettings, preload, run_batch
    from ompn_ros.app.batch_bags import list_bags
    from ompn_ros.app.batch_pool import Stop

    preload(args.checkpoint, device)  # a bad checkpoint refuses the run, not every bag
    detector, line = detector_settings(args.checkpoint, args.detector_config)
    print(f"ompn_segment: {line}", file=sys.stderr)
    settings = BatchSettings(
        checkpoint=args.checkpoint, detector=detector.online, duration_model=detector.duration_model,
        head=detector.head,
        out=Path(args.out), annotate=Path(args.annotate) if args.annotate else None,
        reader_config=args.reader_config, domain=args.domain, on_error=args.on_error, device=device)
    bags = list_bags(args.bags)
    _check_copies(settings.annotate, bags)
    shard = args.num_shards, args.shard_index
    mine = shards.select(bags, lambda bag: bag.key, *shard) if args.num_shards else list(enumerate(bags))
    todo = [bag for _, bag in mine]
    note = functools.partial(_manifest, settings, shard, [(p, b.key) for p, b in mine], len(bags))
    note("running")
    start = time.perf_counter()

    def progress(doc: dict[str, Any], done: int, total: int) -> None:
        print("ompn_segment: " + batch_table.status_line(doc, done, total, time.perf_counter() - start),
              file=sys.stderr, flush=True)

    with Stop() as stop:
        docs = run_batch(settings, todo, args.jobs, progress, stop, clean=args.num_shards is None)
        folder = shards.shard_dir(settings.out, *shard) if args.num_shards else settings.out
        summary = batch_table.write_outputs(folder, docs, time.perf_counter() - start)
        note("interrupted" if stop.requested else "complete")
    print(json.dumps(summary, indent=1))
    print(f"ompn_segment: {batch_table.summary_line(summary)}", file=sys.stderr)
    if stop.signum is not None:
        name = signal.Signals(stop.signum).name
        print(f"ompn_segment: stopped by {name} after {len(docs)} of {len(todo)} bags; the same command "
              "finishes the rest (complete bags are skipped)", file=sys.stderr)
        return 128 + stop.signum
    return SOME_REFUSED if summary["refused"] else 0


def is_batch_command(words: list[str]) -> bool:
    """True when the command line ``words`` runs batch mode (``--bags``)."""
    return any(word == "--bags" or word.startswith("--bags=") for word in words)


def end_batch_command(code: int) -> None:
    """End the batch command's process with ``code`` without the interpreter's teardown of torch,
    numba and the loaded modules (about 0.7 s of CPU, serial after the last bag; docs/scale.md): every
    output is written and closed by now; stdout and stderr are flushed first."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _manifest(settings: BatchSettings, shard: tuple[int | None, int | None], mine: list[tuple[int, str]],
              total: int, status: str) -> None:
    from ompn_ros.app import shards

    count, index = shard
    if count is not None and index is not None:
        shards.write_manifest(settings.out, count, index, mine, total, settings.fingerprint(), status)


AGGREGATE_DOC = """ompn_segment aggregate: merge the shards of a run into one table (and one dataset).

    ompn_segment aggregate OUT [OUT ...] [--out DIR] [--dataset DIR] [--annotate DIR]

reads OUT/shards/<i>-of-<n>/manifest.json and the shards' records under every OUT given (one folder the
shards shared, or one per machine) and writes DIR/segments.csv (rows in the order of an unsharded run),
DIR/summary.json and DIR/metrics.json.  Shards of bags: missing or failed shards are named, one line
each, and the table holds the others (exit 1).  Shards of a dataset's episodes: with --write-subtasks,
also the one annotated dataset (--annotate, default DIR/dataset), equal to an unsharded run's; a
missing or failed shard is named, one line each, and nothing is written (exit 2).
"""


def aggregate_parser() -> argparse.ArgumentParser:
    parser = make_parser("ompn_segment aggregate", AGGREGATE_DOC)
    parser.add_argument("folders", nargs="+", metavar="OUT", help="the --out folder(s) of the shards")
    parser.add_argument("--out", help="where the merged outputs go (none: the first OUT)")
    parser.add_argument("--dataset", metavar="DIR",
                        help="shards of a dataset: where this machine has the dataset (none: the path the "
                        "shards recorded)")
    parser.add_argument("--annotate", metavar="DIR",
                        help="shards of a dataset run with --write-subtasks: the annotated dataset (none: "
                        "OUT/dataset of --out; a previous one written there is replaced)")
    return parser


def run_aggregate(args: argparse.Namespace) -> int:
    """Merge the shards under ``args.folders``: 0 when every shard finished and no bag was refused."""
    from ompn_ros.app import batch_table, lerobot_shards, shards

    del lerobot_shards  # imported for the episodes' merger it adds to shards.MERGERS

    folders = [Path(f) for f in args.folders]
    out = Path(args.out) if args.out else folders[0]
    result = shards.aggregate(folders)
    problems = shards.shard_lines(result)
    if problems and result.kind not in shards.PARTIAL:
        for line in problems:
            print(f"ompn_segment aggregate: error: {line}", file=sys.stderr)
        return 2  # one annotated dataset cannot be partial: nothing was written
    target = shards.MergeTarget(out, Path(args.annotate) if args.annotate else None,
                                Path(args.dataset) if args.dataset else None)
    summary = shards.merge_outputs(result, target)
    summary["shards"] = {"count": result.count, "complete": result.complete, "missing": result.missing,
                         "failed": {str(k): v for k, v in result.failed.items()}}
    batch_table.write_summary(out, summary)
    print(json.dumps(summary, indent=1))
    line = batch_table.summary_line(summary) if result.kind == "bags" else (
        f"{summary['episodes']} episodes, {summary['segments']} segments")
    print(f"ompn_segment: {len(result.complete)} of {result.count} shards complete; {line}", file=sys.stderr)
    for line in problems:
        print(f"ompn_segment: {line}", file=sys.stderr)
    return SOME_REFUSED if problems or summary.get("refused") else 0
