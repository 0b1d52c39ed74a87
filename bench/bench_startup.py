"""Start-up benchmark: ``--help`` of every command, ``ompn_node`` from launch to active, training threads.

1. ``--help``: each console script's entry point is run as its wrapper runs it
   (``sys.argv = [prog, '--help']; main()``), in a fresh interpreter, ``--reps`` times; the figure is
   the median wall time, and whether torch was imported on the way (it must not be).
2. ``ompn_node`` with the quickstart's parameters (``config/ompn_node_dial.yaml``, the shipped Dial
   checkpoint): the wall time from ``Popen`` to its ``activated`` log line, ``--reps`` times, inside
   the loopback containment (:mod:`ompn_ros.ros.containment`).
3. ``--threads``: seconds per training iteration of the shipped Dial config on synthetic Dial-sized
   data, with ``train.threads`` at ``auto`` and at a fixed count, while ``--load`` busy processes
   spin on the machine (0 = as found).  Slow: minutes on a loaded machine.

The machine's load average and usable cores are printed with the figures: both change them.

Run: ``.venv/bin/python bench/bench_startup.py [--reps 3] [--parts help,node,threads] [--load 2]``
from the repository root.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from ompn_ros.ros import containment  # noqa: E402 (after the path insert)

containment.contain(os.environ)  # loopback + shared memory only, a per-run ROS_DOMAIN_ID

COMMANDS = {  # console script -> entry point (setup.py)
    "ompn_node": "ompn_ros.nodes.ompn_node:main",
    "ompn_segment": "ompn_ros.cli.segment:main",
    "ompn_train": "ompn_ros.cli.train:main",
    "ompn_collect": "ompn_ros.cli.collect:main",
    "ompn_ensemble": "ompn_ros.cli.ensemble:main",
    "ompn_closed_loop": "ompn_ros.cli.closed_loop:main",
    "bag_recorder": "ompn_ros.nodes.bag_recorder:main",
    "episode_monitor": "ompn_ros.nodes.episode_monitor:main",
    "dial_sim": "sim_nodes.dial.node:main",
    "craft_sim": "sim_nodes.craft.node:main",
}
PROBE = ("import sys; from {module} import {func}; sys.argv = [{prog!r}, '--help']\n"
         "try:\n    {func}()\nexcept SystemExit:\n    pass\n"
         "print('TORCH' if 'torch' in sys.modules else 'NOTORCH', file=sys.stderr)")


TREE = ROOT  # the source tree timed (--tree: another checkout, e.g. the previous release, for an A/B)


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(TREE), "OMP_NUM_THREADS": "1"}


def bench_help(reps: int) -> dict[str, Any]:
    """Median wall seconds of ``<command> --help`` and whether torch was imported."""
    out: dict[str, Any] = {}
    for prog, entry in COMMANDS.items():
        module, func = entry.split(":")
        times, torch = [], False
        for _ in range(reps):
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", PROBE.format(module=module, func=func, prog=prog)],
                                  env=_env(), capture_output=True, text=True, cwd=TREE, check=False)
            times.append(time.perf_counter() - start)
            torch = torch or "TORCH" in proc.stderr.split()
        out[prog] = {"help_s": round(statistics.median(times), 2), "imports_torch": torch}
        print(f"  {prog:18s} --help {out[prog]['help_s']:6.2f} s  torch imported: {torch}", flush=True)
    return out


def bench_node(reps: int) -> dict[str, Any]:
    """Seconds from launching ``ompn_node`` (quickstart parameters) to its ``activated`` line."""
    params = ROOT / "config" / "ompn_node_dial.yaml"
    entry = "import sys; from ompn_ros.nodes.ompn_node import main; sys.exit(main())"
    command = [sys.executable, "-c", entry, "--ros-args", "--params-file", str(params)]
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        proc = subprocess.Popen(command, env=_env(), cwd=TREE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        assert proc.stdout is not None
        for line in proc.stdout:
            if "activated" in line:
                times.append(time.perf_counter() - start)
                break
        proc.send_signal(2)
        proc.wait(timeout=30)
    result = {"active_s": round(statistics.median(times), 2) if times else None, "runs": len(times)}
    print(f"  ompn_node launch -> active {result['active_s']} s (median of {len(times)})", flush=True)
    return result


def _spin(stop: Any) -> None:
    while not stop.is_set():
        pass


def bench_threads(load: int, fixed: int, iterations: int) -> dict[str, Any]:
    """Seconds per iteration of the Dial config with threads auto and ``fixed`` under ``load`` spinners."""
    stop = multiprocessing.Event()
    spinners = [multiprocessing.Process(target=_spin, args=(stop,), daemon=True) for _ in range(load)]
    for proc in spinners:
        proc.start()
    out: dict[str, Any] = {}
    try:
        time.sleep(65 if load else 0)  # the one-minute load average catches up with the spinners
        for setting in ("auto", str(fixed)):
            out[f"threads_{setting}"] = _iteration_seconds(setting, iterations)
            print(f"  threads={setting}: {out[f'threads_{setting}']} s/iteration "
                  f"(load {os.getloadavg()[0]:.1f})", flush=True)
    finally:
        stop.set()
        for proc in spinners:
            proc.join()
    return out


def _iteration_seconds(setting: str, iterations: int) -> float:
    import tempfile

    env = {k: v for k, v in _env().items() if k != "OMP_NUM_THREADS"}  # auto decides alone
    with tempfile.TemporaryDirectory() as tmp:
        settings = [f"train.threads={setting}", f"train.iterations={iterations}",
                    f"train.eval_every={iterations}", "train.boundary_head=false", "train.candidates=1",
                    "train.candidates_no_final=1", "train.patience=0"]
        config = str(ROOT / "config" / "train_dial.yaml")
        args = ["--synthetic", "continuous", "--episodes", "64", "--config", config, "--out", tmp, "--quiet",
                *[part for item in settings for part in ("--set", item)]]
        subprocess.run([sys.executable, "-m", "ompn_ros.cli.train", *args], env=env, cwd=ROOT, check=True,
                       capture_output=True)
        summary = json.loads((Path(tmp) / "summary.json").read_text())
    return round(float(summary["train_seconds"]) / iterations, 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--parts", default="help,node", help="help, node, threads (comma-separated)")
    parser.add_argument("--load", type=int, default=0, help="busy processes during the threads part")
    parser.add_argument("--fixed", type=int, default=2, help="the fixed thread count to compare with auto")
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--tree", type=Path, default=ROOT, help="the source tree to time (PYTHONPATH)")
    args = parser.parse_args()
    global TREE
    TREE = args.tree.resolve()
    parts = set(args.parts.split(","))
    print(f"cores usable: {len(os.sched_getaffinity(0))}, load average {os.getloadavg()[0]:.1f}", flush=True)
    results: dict[str, Any] = {}
    if "help" in parts:
        results["help"] = bench_help(args.reps)
    if "node" in parts:
        results["node"] = bench_node(args.reps)
    if "threads" in parts:
        results["threads"] = bench_threads(args.load, args.fixed, args.iterations)
    print(json.dumps(results))


if __name__ == "__main__":
    main()
