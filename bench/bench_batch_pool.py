"""Benchmark of ``ompn_segment --bags --jobs N``: does a second worker double the throughput?

Two datasets of another lab's bags (rosbags writer; 39 observation features and 9 action values at
50 Hz, the shipped Dial model's sizes; episodes of 20 s split by 2 s pauses):

* ``long``: ``--long`` bags of ``--minutes`` minutes each (default 200 x 2 min);
* ``short``: ``--short`` bags of 2 s each (default 200): start-up and per-bag costs dominate.

Each is segmented with ``--jobs 1`` and ``--jobs 2`` (and, with ``--spawn``, ``--jobs 2`` with
spawned workers, as before workers were forked warm), side by side in one run, by a randomly
initialised model of the shipped Dial checkpoint's configuration (the same cost per step).  Wall
time of the whole command, start-up included, and the CPU time of all its processes (what the
workers' start-up costs, whatever the load), split into the command's own process (``parent``:
start-up, listing, collecting, the table) and its workers; ``startup`` is the command on one short
bag with ``--jobs 1``: the serial part no number of workers shortens.  One torch thread per process.

``ceiling``, measured right after each dataset's commands: what this machine gives two processes of
fixed work at that moment (a Python loop over a small float32 product, nothing of this package, about
3 s alone): twice the time of one alone over the time of two at once, the median of ``--ceiling-rounds``
alternations (each in ``ceiling_runs``).  On a virtual machine whose two vCPUs share a physical core,
or on a busy host, this falls below 2 and no pool can beat it; ``of_ceiling`` reads the ratio against
it.  ``bound`` is what two whole cores could give at best with the command's serial start:
``jobs1 / (startup + (jobs1 - startup) / 2)``.

    nice .venv/bin/python bench/bench_batch_pool.py [--long 200 --minutes 2 --short 200 --spawn]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig

ROOT = Path(__file__).resolve().parents[1]
HZ = 50
EPISODE_S = 20.0
SPEC = {"reader": {
    "namespace": "/lab", "observation": {"topic": "features", "type": layout.FLOAT32_ARRAY},
    "action": {"topic": "cmd", "type": layout.FLOAT32_ARRAY, "dim": 9}, "subtask": None, "labels": "none",
    "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5, "tolerance": 0.03, "stamp": "log",
    "task": "lab", "final_observation": "duplicate"}}
SPAWN = ("import multiprocessing\n"
         "from ompn_ros.app import batch_pool\n"
         "batch_pool.pool_context = lambda device: multiprocessing.get_context('spawn')\n")
COMMAND = ("import resource, sys\n"
           "{setup}"
           "from ompn_ros.cli import segment\n"
           "def report():\n"
           "    own = resource.getrusage(resource.RUSAGE_SELF)\n"
           "    print('bench_parent_cpu_s', own.ru_utime + own.ru_stime, file=sys.stderr, flush=True)\n"
           "end = getattr(segment, 'end_batch_command', None)\n"
           "if end is not None:\n"
           "    segment.end_batch_command = lambda code: (report(), end(code))\n"
           "code = segment.main()\n"
           "report()\n"
           "sys.exit(code)\n")
"""The command as its console script runs it (``main()`` reads ``sys.argv``), printing the CPU time
of its own process (not its workers', nor its exit's) when its work is done."""


def write_bag(path: Path, seed: int, seconds: float) -> int:
    """A bag of ``seconds`` of 50 Hz features and commands, episodes of 20 s; returns its steps."""
    from rosbags.rosbag2 import Writer

    rng = np.random.default_rng(seed)
    t, steps = 1_700_000_000_000_000_000 + seed * 10**12, int(seconds * HZ)
    per_episode = int(EPISODE_S * HZ)
    with Writer(path, version=9) as w:
        ts = m.typestore()
        obs = w.add_connection("/lab/features", layout.FLOAT32_ARRAY, typestore=ts)
        cmd = w.add_connection("/lab/cmd", layout.FLOAT32_ARRAY, typestore=ts)
        for k in range(steps):
            w.write(obs, t, m.serialize(m.float32_array(rng.standard_normal(39))))
            w.write(cmd, t + 5_000_000, m.serialize(m.float32_array(rng.standard_normal(9), "cmd")))
            t += 1_000_000_000 // HZ
            if (k + 1) % per_episode == 0:
                t += 2_000_000_000
    return steps


def make_dataset(root: Path, count: int, seconds: float, first_seed: int) -> tuple[Path, int]:
    steps = sum(write_bag(root / f"bag{i:04d}", first_seed + i, seconds) for i in range(count))
    return root, steps


def segment(bags: Path, model: Path, spec: Path, jobs: int, out: Path,
            spawn: bool = False) -> tuple[float, float, float]:
    """Wall seconds, CPU seconds (user + system, all its processes) and CPU seconds of its own
    process of one batch command."""
    path = f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": path}
    argv = ["--bags", str(bags), "--jobs", str(jobs), "--checkpoint", str(model),
            "--reader-config", str(spec), "--out", str(out)]
    command = [sys.executable, "-c", COMMAND.format(setup=SPAWN if spawn else ""), *argv]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-2000:])
    parent = float(done.stderr.rsplit("bench_parent_cpu_s", 1)[1].split()[0])
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), parent


FIXED_WORK = ("import numpy as np\n"
              "a = np.random.default_rng(0).standard_normal((64, 64)).astype(np.float32)\n"
              "s = 0.0\n"
              "for i in range({loops}):\n"
              "    s += float((a @ a[:, :1]).sum()) * 1e-9\n")
"""The fixed work of :func:`ceiling`: one thread, about a segmenter step's mix of Python and numpy."""


def ceiling(rounds: int = 3, loops: int = 1_000_000) -> list[float]:
    """Twice the time of one :data:`FIXED_WORK` process alone over the time of two at once, for each of
    ``rounds`` alternations (2.0: two whole cores)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    command = [sys.executable, "-c", FIXED_WORK.format(loops=loops)]

    def timed(copies: int) -> float:
        start = time.perf_counter()
        running = [subprocess.Popen(command, env=env) for _ in range(copies)]
        if any(p.wait() != 0 for p in running):
            raise RuntimeError("the fixed work failed")
        return time.perf_counter() - start

    return [2 * timed(1) / timed(2) for _ in range(rounds)]


def _load() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long", type=int, default=200, help="bags of --minutes each")
    parser.add_argument("--minutes", type=float, default=2.0)
    parser.add_argument("--short", type=int, default=200, help="bags of 2 s each")
    parser.add_argument("--spawn", action="store_true", help="also --jobs 2 with spawned workers (before)")
    parser.add_argument("--ceiling-rounds", type=int, default=3,
                        help="alternations of the fixed work after each dataset (0: none)")
    parser.add_argument("--out", help="JSON results file (none: print only)")
    args = parser.parse_args()
    results: dict[str, dict[str, float | str]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_batch_pool_") as tmp:
        root = Path(tmp)
        config = OMPNConfig(obs_dim=39, action_type="continuous", action_dim=9, n_slots=2, slot_size=64)
        save_checkpoint(root / "model", build_policy(config))
        spec = root / "reader.yaml"
        spec.write_text(yaml.safe_dump(SPEC))
        sets = [("long", args.long, args.minutes * 60), ("short", args.short, 2.0)]
        for name, count, seconds in sets:
            if count <= 0:
                continue
            bags, steps = make_dataset(root / name, count, seconds, 1000 if name == "long" else 5000)
            row: dict[str, float | str] = {"bags": count, "steps": steps, "load_before": _load()}
            runs = [("jobs1", 1, False), ("jobs2", 2, False)]
            runs += [("jobs2_spawn", 2, True)] if args.spawn else []
            for label, jobs, spawn in runs:
                out = root / f"out_{name}_{label}"
                wall, cpu, parent = segment(bags, root / "model", spec, jobs, out, spawn)
                row[f"{label}_s"], row[f"{label}_cpu_s"] = wall, cpu
                row[f"{label}_parent_cpu_s"], row[f"{label}_workers_cpu_s"] = parent, cpu - parent
            if name == "short":
                one = root / "one_bag.txt"
                one.write_text(f"{sorted(bags.iterdir())[0]}\n")
                wall, cpu, _ = segment(one, root / "model", spec, 1, root / "out_startup")
                row["startup_s"], row["startup_cpu_s"] = wall, cpu
            row["ratio"] = float(row["jobs1_s"]) / float(row["jobs2_s"])
            if "startup_s" in row:
                startup = float(row["startup_s"])
                row["bound"] = float(row["jobs1_s"]) / (startup + (float(row["jobs1_s"]) - startup) / 2)
            if args.ceiling_rounds > 0:
                spread = ceiling(args.ceiling_rounds)
                row["ceiling_runs"] = ", ".join(f"{r:.2f}" for r in spread)
                row["ceiling"] = float(np.median(spread))
                row["of_ceiling"] = float(row["ratio"]) / float(row["ceiling"])
            if args.spawn:
                row["ratio_spawn"] = float(row["jobs1_s"]) / float(row["jobs2_spawn_s"])
            row["load_after"] = _load()
            results[name] = row
            print(json.dumps({name: row}), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
