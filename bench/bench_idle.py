"""Benchmark of the idle gate (``ompn_node``'s ``idle_s``): time per observation against the idle steps held.

A robot that waits keeps its driver publishing; with ``idle_s`` every idle observation is held until
the rule decides it (:class:`ompn_ros.data.cuts.IdleGate`).  The figure is the time of one
``IdleGate.push`` of an idle observation (the median of ``--pushes`` pushes) after ``held`` idle
observations were held, for each ``held`` of ``--held``: it should stay flat from 0 to 100 000.
Observations of 39 values (Dial's size) at 500 Hz stamps; ``idle_s`` beyond every pause.

Run: ``.venv/bin/python bench/bench_idle.py [--held 0 1000 10000 100000] [--pushes 2000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ompn_ros.data.cuts import IdleGate

STEP_NS = 2_000_000  # 500 Hz


def push_cost_us(held: int, pushes: int) -> float:
    """Median µs of one idle push with ``held`` idle observations already held."""
    gate = IdleGate(10**18, idle_speed=0.01)
    moving = np.arange(39, dtype=np.float32)
    stamp = 0
    for k in range(3):  # an open episode
        stamp += STEP_NS
        gate.push(moving + k, stamp)
    idle = moving + 2
    for _ in range(held):
        stamp += STEP_NS
        gate.push(idle, stamp)
    times = np.empty(pushes)
    for i in range(pushes):
        stamp += STEP_NS
        t0 = time.perf_counter_ns()
        gate.push(idle, stamp)
        times[i] = time.perf_counter_ns() - t0
    return float(np.median(times)) / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--held", type=int, nargs="+", default=[0, 1_000, 10_000, 100_000])
    parser.add_argument("--pushes", type=int, default=2_000)
    args = parser.parse_args()
    print("| idle observations held | µs per observation (p50) |")
    print("|---|---|")
    for held in args.held:
        print(f"| {held} | {push_cost_us(held, args.pushes):.2f} |", flush=True)


if __name__ == "__main__":
    main()
