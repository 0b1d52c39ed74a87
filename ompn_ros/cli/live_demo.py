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

from ompn_ros.cli._common import make_parser, run_cli
from ompn_ros.cli._live import add_live_demo_arguments, run_live_demo

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    return add_live_demo_arguments(make_parser("ompn_live_demo", __doc__.splitlines()[0]))


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli(build_parser(), run_live_demo, argv)


if __name__ == "__main__":
    sys.exit(main())
