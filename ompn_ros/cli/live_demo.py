"""ompn_demo live segmentation: a sim and ompn_node as separate processes, segmenting live over ROS 2.

The sim (expert mode) publishes observations and the ground-truth subtask index; ompn_node steps
the ordered memory on every observation and publishes boundary events.  The monitor subscribes to
both, prints every detected boundary next to the true one, and ends with the online F1, alignment
accuracy and latency summary plus a saved plot of π over time (ompn_ros.app.live).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ompn_ros.app import live
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.cli._common import add_live_demo_arguments, make_parser, run_cli

__all__ = ["build_parser", "main", "run"]


def build_parser() -> argparse.ArgumentParser:
    return add_live_demo_arguments(make_parser("ompn_live_demo", __doc__.splitlines()[0]))


def run(args: argparse.Namespace) -> int:
    """The live demo for parsed arguments (see :func:`ompn_ros.cli._common.add_live_demo_arguments`)."""
    checkpoint = args.checkpoint or shipped_checkpoint(args.domain)
    return live.run_demo(args.domain, checkpoint, args.episodes, args.rate, args.seed, args.out, args.timeout,
                         params_file=args.params_file, sim_params=args.sim_param)


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
