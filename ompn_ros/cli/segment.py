"""ompn_segment: replay bags through the StreamingSegmenter; compare and tune detectors.

Replay (the same class the live node runs):

    ompn_segment --bag PATH --checkpoint DIR [--reader-config YAML] [--out DIR] [--detector-config YAML]
    ompn_segment --bags FOLDER|GLOB|LIST --jobs N --checkpoint DIR [--annotate DIR] [--out DIR]
    ompn_segment --dataset DIR --checkpoint DIR [--dataset-spec YAML] [--write-subtasks FORMAT [--in-place]]
    ompn_segment --bags ... --num-shards N --shard-index I ...;  ompn_segment aggregate OUT [OUT ...]

writes pi.npz (per episode ep<i>_{pi,p_hat,pi_end,expected_position,score}), boundaries.json
(online events and ground truth), metrics.json (online vs offline, when the bag has subtask
labels), episode_<i>.png plots and, for a bag, read_report.json/.txt (what the reader kept and
dropped; --on-error skip_tail keeps the episodes before a corrupt tail).

Tuning (choose the per-domain node defaults from measurements):

    ompn_segment --tune --checkpoint DIR (--bag PATH | --generate N --domain D) \\
        [--write-config config/ompn_node_<domain>.yaml]

The tuning objective is boundary F1 at tolerance 1 or the alignment accuracy (strict decoding), then
the other one, then the lower mean detection delay; settings within one standard error of the best
objective (over the tuning episodes) count as tied on it (docs/design.md#detector-grid).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ompn_ros.app import segment_setup
from ompn_ros.app.segment_setup import (
    DEFAULT_OBJECTIVE,
    DEVICES,
    DURATION_DELAY,
    DURATION_LAG,
    MAX_LAG,
    OBJECTIVES,
)
from ompn_ros.cli._batch import (
    add_batch_arguments,
    aggregate_parser,
    check_batch_arguments,
    end_batch_command,
    is_batch_command,
    run_aggregate,
    run_batch_cli,
)
from ompn_ros.cli._common import make_parser, run_cli
from ompn_ros.cli._dataset import add_dataset_arguments, run_dataset_cli

if TYPE_CHECKING:
    from ompn_ros.app.detector_tuning import Tuned


def build_parser() -> argparse.ArgumentParser:
    p = make_parser("ompn_segment", __doc__)
    _add_input_arguments(p)
    _add_replay_arguments(p)
    _add_tune_arguments(p)
    return p


def _add_input_arguments(p: argparse.ArgumentParser) -> None:
    """What is replayed and how: the bag or bags, the checkpoint, the reader, the detector, the device."""
    p.add_argument("--bag", help="bag file/directory/glob to replay (none: give --bags or --generate)")
    add_batch_arguments(p)
    add_dataset_arguments(p)
    p.add_argument(
        "--checkpoint",
        required=True,
        help="checkpoint directory (safetensors + JSON), or an ensemble directory (ensemble.json)",
    )
    p.add_argument(
        "--reader-config",
        help="bag reader spec YAML, e.g. config/reader_craft.yaml (none: the preset of --domain)",
    )
    p.add_argument(
        "--on-error",
        choices=("raise", "skip_tail"),
        default="raise",
        help="a corrupt bag: stop with an error, or keep the episodes before the corrupt tail",
    )
    p.add_argument(
        "--domain",
        choices=("craft", "dial"),
        help="reader preset / episode generator / config name (none: the reader's defaults)",
    )
    p.add_argument(
        "--detector-config",
        help="YAML with detector_* keys, e.g. config/ompn_node_craft.yaml (none: the checkpoint's own "
        "detector.json, else the detector defaults)",
    )
    p.add_argument(
        "--device", choices=DEVICES, default="auto",
        help="replay: cpu steps the compiled kernel; cuda steps the policy's torch module on the GPU; "
        "auto is cpu (a batch-1 replay is faster on the CPU than on a GPU)",
    )


def _add_replay_arguments(p: argparse.ArgumentParser) -> None:
    """What a replay writes: the output folder, an annotated copy, the plots."""
    p.add_argument("--out", default="segment_out", help="output directory (replay mode)")
    p.add_argument(
        "--annotate",
        metavar="OUT",
        help="replay mode: also write OUT, an mcap copy of the bag with the node's ~/pi, ~/segment and "
        "~/boundary added at the observation stamps (--bags: OUT/<key> per bag; none: no copy)",
    )
    p.add_argument("--overwrite", action="store_true", help="with --annotate: replace an existing OUT")
    p.add_argument("--plot-episodes", type=int, default=3, help="number of episodes to plot")


def _add_tune_arguments(p: argparse.ArgumentParser) -> None:
    """--tune, its grid and objective, and the generated episodes a tuning or a replay may run on."""
    p.add_argument("--tune", action="store_true", help="grid-search the online detector instead of replaying")
    p.add_argument(
        "--generate", type=int, default=0, help="tune/replay on N freshly generated expert episodes"
    )
    p.add_argument("--seed", type=int, default=10_000, help="first seed of --generate")
    p.add_argument(
        "--write-config",
        help="with --tune: write the chosen settings as an ompn_node params file and into the "
        "checkpoint's detector.json (none: print only)",
    )
    p.add_argument(
        "--lag", type=int, default=DURATION_LAG, choices=range(MAX_LAG + 1), metavar=f"0..{MAX_LAG}",
        help="with --tune: the lag of the 'hsmm' and 'head_hsmm' detectors (boundaries come >= lag + 1 "
        "steps late); the 'hsmm' one is fitted "
        "beside the threshold grid (it is chosen when it gains 1 point of alignment and keeps F1@1 within "
        "1 point)",
    )
    p.add_argument(
        "--max-delay", type=float, default=DURATION_DELAY, metavar="STEPS",
        help="with --tune: the mean delay in steps the 'hsmm' and 'head_hsmm' detectors' thresholds may cost",
    )
    p.add_argument(
        "--long-subtasks", action="store_true",
        help="with --tune: subtasks of tens of steps (e.g. an arm at 25 Hz): also try shortest segments of "
        "1/4 and 1/2 the episodes' typical subtask length, then a boundary offset "
        "(docs/design.md#detector-grid)",
    )
    p.add_argument(
        "--objective",
        choices=OBJECTIVES,
        default=None,
        help="with --tune: maximise boundary F1 (tol 1) or alignment first; settings within one standard "
        "error of the best count as tied and the other metric decides "
        f"(none: per domain, {DEFAULT_OBJECTIVE}; f1 without --domain)",
    )


def _tune(args: argparse.Namespace, tuned: Tuned) -> int:
    from ompn_ros.app import replay
    from ompn_ros.app.detector_tuning import write_tuned

    print(json.dumps(replay.json_safe(tuned.doc()), indent=1))
    if args.write_config:
        source = args.bag or f"{args.generate} generated {args.domain} episodes (seeds from {args.seed})"
        written = write_tuned(tuned, args.write_config, args.domain, args.checkpoint, source)
        print(f"ompn_segment: wrote {args.write_config}, {written}", file=sys.stderr)
    return 0


def _run(args: argparse.Namespace) -> int:
    import torch  # here, not at the top: --help stays light (bench/bench_startup.py)

    from ompn_ros.app import replay
    from ompn_ros.app.detector_tuning import tune_detector
    from ompn_ros.app.errors import ReplayError
    from ompn_ros.app.read_report import write_read_report
    from ompn_ros.app.replay import replay_all

    device = segment_setup.replay_device(args.device)  # before any bag is read
    if args.dataset:
        return run_dataset_cli(args, device)
    check_batch_arguments(args)
    if args.bags:
        return run_batch_cli(args, device)
    if args.annotate and (args.tune or not args.bag):
        raise ReplayError("--annotate copies the replayed bag: it needs --bag and no --tune")
    torch.set_num_threads(1)
    policy = segment_setup.load_stepper(args.checkpoint, device)
    episodes, read = segment_setup.load_episodes(args.bag, args.reader_config, args.domain, args.on_error,
                                                 args.generate, args.seed, args.checkpoint)
    if read is not None:
        print(read.report.summary(), file=sys.stderr)
        if not args.tune:
            write_read_report(Path(args.out), replay.read_report_doc(read, args.on_error))
    if not episodes:
        raise ReplayError(f"no episodes found in {args.bag}")
    if args.tune:
        stored, _ = segment_setup.detector_settings(args.checkpoint, None)
        tuned = tune_detector(policy, episodes, args.objective, args.domain, args.lag, args.max_delay,
                              args.long_subtasks, stored.head)
        return _tune(args, tuned)
    settings, line = segment_setup.detector_settings(args.checkpoint, args.detector_config)
    config, model = settings.online, settings.duration_model
    replays = replay_all(policy, episodes, config, model, settings.head)
    summary = replay.run_replay(policy, episodes, config, Path(args.out), args.plot_episodes, replays=replays,
                                duration_model=model, head=settings.head)
    print(json.dumps(replay.json_safe(summary), indent=1))
    print(f"ompn_segment: {line}", file=sys.stderr)
    if args.annotate:
        spec = replay.reader_spec(args.reader_config, args.domain, args.checkpoint)
        done = replay.annotate(args.bag, Path(args.annotate), episodes, replays, spec,
                               overwrite=args.overwrite)
        print(f"ompn_segment: annotated copy written to {done.out}", file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    if words[:1] == ["aggregate"]:
        return run_cli(aggregate_parser(), run_aggregate, words[1:])
    code = run_cli(build_parser(), _run, words)
    if argv is None and is_batch_command(words):  # the command itself, not a caller in this process
        end_batch_command(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
