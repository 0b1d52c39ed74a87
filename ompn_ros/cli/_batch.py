"""``ompn_segment --bags SOURCE --jobs N``: segment many bags over a pool of processes.

The options and the command-line shell of batch mode; the work is ``app/batch.py``
(tasks, resuming) and ``app/batch_table.py`` (table, summary, metrics).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ompn_ros.app.errors import ReplayError
from ompn_ros.app.segment_setup import detector_settings, load_stepper

if TYPE_CHECKING:  # the batch services load when a batch runs, not for --help
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


def check_batch_arguments(args: argparse.Namespace) -> None:
    """Refuse option combinations batch mode does not take (one line naming the option)."""
    if args.bags and (args.bag or args.tune or args.generate):
        raise ReplayError("--bags replays many bags: give it without --bag, --tune and --generate")
    if args.jobs < 1:
        raise ReplayError(f"--jobs must be at least 1, got {args.jobs}")


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
    """Segment the bags of ``--bags`` on ``device`` ('cpu' or 'cuda'); 0 when every bag was segmented,
    :data:`SOME_REFUSED` otherwise."""
    from ompn_ros.app import batch_table
    from ompn_ros.app.batch import BatchSettings, run_batch
    from ompn_ros.app.batch_bags import list_bags

    load_stepper(args.checkpoint, device)  # a bad checkpoint refuses the run, not every bag
    detector, line = detector_settings(args.checkpoint, args.detector_config)
    print(f"ompn_segment: {line}", file=sys.stderr)
    settings = BatchSettings(
        checkpoint=args.checkpoint, detector=detector.online, duration_model=detector.duration_model,
        head=detector.head,
        out=Path(args.out), annotate=Path(args.annotate) if args.annotate else None,
        reader_config=args.reader_config, domain=args.domain, on_error=args.on_error, device=device)
    bags = list_bags(args.bags)
    _check_copies(settings.annotate, bags)
    start = time.perf_counter()
    docs = run_batch(settings, bags, args.jobs, progress=lambda doc, done, total: print(
        "ompn_segment: " + batch_table.status_line(doc, done, total, time.perf_counter() - start),
        file=sys.stderr, flush=True))
    summary = batch_table.write_outputs(settings.out, docs, time.perf_counter() - start)
    print(json.dumps(summary, indent=1))
    print(f"ompn_segment: {batch_table.summary_line(summary)}", file=sys.stderr)
    return SOME_REFUSED if summary["refused"] else 0
