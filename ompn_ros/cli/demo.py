"""ompn_demo (make demo): the main job on the shipped defaults.

--smoke runs the DDS self-check: smoke_listener and smoke_talker as two processes.  Without it, the
live segmentation demo runs: a sim and ompn_node as processes, monitored (ompn_ros.app.live).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from ompn_ros.cli._common import add_live_demo_arguments, make_parser, run_cli
from ompn_ros.cli._live import run_live_demo
from ompn_ros.ros.env import child_env


def run_smoke(count: int = 100, rate: float = 100.0) -> int:
    """Two processes exchange ``count`` messages; prints the listener's summary."""
    env = child_env()
    common = ["--ros-args", "-p", f"count:={count}", "-p", f"rate:={rate}"]
    start = time.perf_counter()
    listener = subprocess.Popen(
        [sys.executable, "-m", "ompn_ros.nodes.smoke", "listener", *common, "-p", "timeout:=15.0"],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    talker = subprocess.run(
        [sys.executable, "-m", "ompn_ros.nodes.smoke", "talker", *common, "-p", "wait_for_subscriber:=15.0"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    out, _ = listener.communicate(timeout=60)
    summary = json.loads(out.strip().splitlines()[-1]) if out.strip() else {"lost": count}
    print(
        f"smoke: talker exit {talker.returncode}, listener {summary}, "
        f"{time.perf_counter() - start:.1f} s (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']})"
    )
    return 0 if talker.returncode == 0 and summary.get("lost") == 0 else 1


def build_parser() -> argparse.ArgumentParser:
    parser = make_parser("ompn_demo", __doc__.split("\n\n")[0])
    parser.add_argument("--smoke", action="store_true", help="only the two-process DDS self-check")
    return add_live_demo_arguments(parser)


def _run(args: argparse.Namespace) -> int:
    return run_smoke() if args.smoke else run_live_demo(args)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
