"""ompn_train: behaviour-clone an OMPN from rosbag2 recordings (or synthetic data).

Usage:

    ompn_train --bags BAG [BAG ...] --config config/train_dial.yaml --out DIR [--resume] [--set k=v ...]
    ompn_train --dataset DIR [--dataset-spec YAML] --config config/train_dial.yaml --out DIR
    ompn_train --synthetic discrete --config config/train_craft.yaml --out DIR --set train.iterations=50
    torchrun --nproc_per_node=2 -m ompn_ros.cli.train --synthetic discrete --out DIR ...

The YAML config has three sections:

    model: {n_slots: 3, slot_size: 128, sketch_mode: none, memory_update: paper, ...}   # OMPNConfig
    train: {lr: 0.001, batch_size: 256, clip_norm: 0.2, bptt: 64, ...}                  # TrainConfig
    data:  {domain: craft, on_error: raise}   # craft | dial fix obs_dim/action_type/action_dim

obs_dim, action_type and action_dim come from data.domain (ompn_ros.layout) or, for --synthetic,
from the synthetic task; --set section.key=value overrides any entry (values are parsed as YAML).
--out sets train.out_dir and must be empty unless --resume or --overwrite is given.  With
data.on_error=skip_tail, a bag with a corrupt tail keeps the episodes before it; what the reader
kept and dropped is printed and stored as OUT/read_report.json (and .txt), with whether the data is
likely enough (demonstrations against the smallest measured runs); the last lines before the JSON
summary say what to expect of the checkpoint.  With the reader's
final_observation: auto, one run per option of final_options trains under OUT/final_observation/ and
the one validation prefers is kept (OUT/final_observation.json).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ompn_ros.cli._common import make_parser, run_cli

if TYPE_CHECKING:  # the services load when training runs, not for --help (torch: seconds)
    from ompn_ros.app.training import TrainingData

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = make_parser("ompn_train", __doc__)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--bags", nargs="+", metavar="PATH", help="rosbag2 directories or files to read")
    source.add_argument("--dataset", metavar="DIR", help="a LeRobot v3 dataset (local folder) to read")
    source.add_argument(
        "--synthetic",
        choices=("discrete", "continuous", "craft_shaped"),
        help="train on a synthetic task instead of bags (smoke runs)",
    )
    parser.add_argument(
        "--dataset-spec", metavar="YAML",
        help="with --dataset: which features are the observation, the action, the labels "
        "(config/dataset_example.yaml; none: observation.state, action, no labels)")
    parser.add_argument("--episodes", type=int, default=200, help="synthetic episodes to generate")
    parser.add_argument("--config", help="YAML config (sections model/train/data); none = all defaults")
    parser.add_argument("--out", required=True, type=Path, help="output directory (checkpoints, logs)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="continue from OUT/train_state")
    mode.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the checkpoints, state and logs of an earlier run in OUT",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config entry, e.g. --set train.lr=5e-4 (repeatable)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar, warnings only")
    return parser


def _run(args: argparse.Namespace) -> int:
    from ompn_ros.app import training
    from ompn_ros.app.data_amount import data_amount, expectation
    from ompn_ros.app.errors import TrainSetupError
    from ompn_ros.app.final_choice import train_auto
    from ompn_ros.app.read_report import write_read_report
    from ompn_ros.app.training import apply_overrides, load_config

    logging.basicConfig(
        level=logging.WARNING if args.quiet else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
    )
    config = load_config(args.config)
    apply_overrides(config, args.overrides)
    training.check_device(config)
    training.prepare_out_dir(args.out, args.resume, args.overwrite)
    if args.dataset_spec and not args.dataset:
        raise TrainSetupError("--dataset-spec goes with --dataset DIR")
    spec = None if args.synthetic or args.dataset else training.reader_spec(config["data"])
    if spec is not None and spec.final_observation == "auto":
        summary, option = train_auto(args.bags, config, spec, args.out, args.resume, args.quiet,
                                     shown=_print_read)
        _print_summary(summary, option)
        return 0
    if args.synthetic:
        data = training.synthetic_data(args.synthetic, args.episodes, config["data"])
    elif args.dataset:
        data = training.dataset_data(args.dataset, config["data"], args.dataset_spec)
    else:
        data = training.bag_data(args.bags, config["data"], spec)
    model_config, train_config = training.build_configs(config, data, args.out, args.resume, args.quiet)
    amount = data_amount(data.episodes, train_config.val_ratio, training.labelled(train_config, data))
    if data.report:
        data.report["summary"] = "\n".join([*filter(None, [data.report.get("summary")]), *amount.lines()])
        data.report["data_amount"] = amount.to_dict()
        print(data.report["summary"], file=sys.stderr)
        write_read_report(args.out, data.report)
    summary = training.run_training(data, model_config, train_config, args.out)
    if summary is not None:
        selection = train_config.selection if amount.labelled else "agreement"
        print("\n".join(expectation(amount, selection, summary["best"])), file=sys.stderr)
    _print_summary(summary)
    return 0


def _print_read(option: str, data: TrainingData) -> None:
    print(f"final_observation: auto, row T read as '{option}':\n{data.report['summary']}", file=sys.stderr)


def _print_summary(summary: dict[str, Any] | None, final_observation: str | None = None) -> None:
    """One JSON line: iterations, best iteration, restarts, frames, initialisations trained (and the
    ``final_observation`` option ``auto`` kept)."""
    if summary is None:
        return
    shown = {k: summary[k] for k in ("iterations", "best_iteration", "restarts", "frames")}
    shown["candidates"] = max(1, len(summary["candidates"]))  # initialisations trained (candidates.json)
    if final_observation is not None:
        shown["final_observation"] = final_observation
    print(json.dumps(shown))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ompn_train console script; returns the process exit code."""
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
