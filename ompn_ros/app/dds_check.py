"""The DDS self-check of ``ompn_demo --smoke``: a talker and a listener exchange messages as two
processes (:mod:`ompn_ros.nodes.dds_probe`) under the containment environment of the child processes."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from ompn_ros.ros.env import child_env


def run_dds_check(count: int = 100, rate: float = 100.0) -> int:
    """Two processes exchange ``count`` messages; prints the listener's summary."""
    env = child_env()
    common = ["--ros-args", "-p", f"count:={count}", "-p", f"rate:={rate}"]
    start = time.perf_counter()
    listener = subprocess.Popen(
        [sys.executable, "-m", "ompn_ros.nodes.dds_probe", "listener", *common, "-p", "timeout:=15.0"],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    talker = subprocess.run(
        [sys.executable, "-m", "ompn_ros.nodes.dds_probe", "talker", *common,
         "-p", "wait_for_subscriber:=15.0"],
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
