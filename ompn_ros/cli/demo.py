"""ompn_demo (make demo): the main job on the shipped defaults.

--smoke runs the DDS self-check: smoke_listener and smoke_talker as two processes.  Without it, the
live segmentation demo runs: a sim and ompn_node as processes, monitored (ompn_ros.app.live).
"""

from __future__ import annotations

import argparse
import sys

from ompn_ros.app.dds_check import run_dds_check
from ompn_ros.cli._common import make_parser, run_cli
from ompn_ros.cli._live import add_live_demo_arguments, run_live_demo


def build_parser() -> argparse.ArgumentParser:
    parser = make_parser("ompn_demo", __doc__.split("\n\n")[0])
    parser.add_argument("--smoke", action="store_true", help="only the two-process DDS self-check")
    return add_live_demo_arguments(parser)


def _run(args: argparse.Namespace) -> int:
    return run_dds_check() if args.smoke else run_live_demo(args)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
