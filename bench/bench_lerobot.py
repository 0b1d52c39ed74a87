"""Benchmark: segmenting a LeRobot dataset against the same episodes from bags, and the dataset
path's peak memory as the dataset grows.

The same generated episodes (``--frames`` frames each: 39 observation floats drifting as a random
walk, 9 actions; the shipped Dial checkpoint) are written twice: as a LeRobot v3.0 dataset (frame files
of ``--per-file`` episodes, written here with pyarrow in LeRobot's layout: LeRobot's own writer takes
about 2 ms a frame) and as rosbag2 bags of ``--per-file`` episodes each (``write_episodes``).  Then,
each in a fresh process with one thread, ``ompn_segment --dataset DIR`` and ``ompn_segment --bags DIR
--jobs 1`` segment them (the online detector, the table of segments); the wall time, the CPU time (on
a shared machine the figure to compare: the wall time follows the other processes' load) and the
process's peak resident memory are recorded.  With ``--sizes 100,1000`` the dataset run is repeated
on both sizes: its peak memory should not grow with the number of episodes.

    OMP_NUM_THREADS=1 nice .venv/bin/python bench/bench_lerobot.py [--sizes 100,1000] [--frames 500]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data import write_episodes
from ompn_ros.data.episode import Episode

ROOT = Path(__file__).resolve().parents[1]
MEASURE = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
           "done = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, "
           "text=True); sys.stderr.write(done.stderr[-2000:]); "
           "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
           "print(done.returncode, time.perf_counter() - t, u.ru_utime + u.ru_stime, u.ru_maxrss)")


def episodes(count: int, frames: int, seed: int = 0) -> list[Episode]:
    rng = np.random.default_rng(seed)
    found = []
    for _ in range(count):
        obs = np.cumsum(rng.normal(0, 0.02, (frames, 39)), axis=0).astype(np.float32)
        actions = rng.uniform(-1, 1, (frames - 1, 9)).astype(np.float32)
        labels = np.minimum(np.arange(frames - 1) * 4 // (frames - 1), 3).astype(np.int64)
        found.append(Episode(observations=obs, actions=actions, subtask=labels, sketch=np.arange(1, 5),
                             task="dial"))
    return found


def write_dataset(root: Path, eps: list[Episode], per_file: int, fps: int = 25) -> None:
    """``eps`` in LeRobot v3.0's layout (what ``data/lerobot/layout.py`` reads)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    (root / "meta").mkdir(parents=True)
    feature = {"observation.state": [39], "action": [9]}
    info = {"codebase_version": "v3.0", "fps": fps, "total_episodes": len(eps),
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet", "features": {
                **{k: {"dtype": "float32", "shape": v, "names": None} for k, v in feature.items()},
                **{k: {"dtype": t, "shape": [1], "names": None} for k, t in (
                    ("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                    ("index", "int64"), ("task_index", "int64"))}}}
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    index = 0
    for file, first in enumerate(range(0, len(eps), per_file)):
        group = eps[first:first + per_file]
        n = [ep.length + 1 for ep in group]
        actions = np.concatenate([np.concatenate([ep.actions, ep.actions[-1:]]) for ep in group])
        columns = {
            "observation.state": pa.FixedSizeListArray.from_arrays(
                np.concatenate([ep.observations for ep in group]).ravel(), 39),
            "action": pa.FixedSizeListArray.from_arrays(actions.ravel(), 9),
            "timestamp": pa.array(np.concatenate([np.arange(k) / fps for k in n]).astype(np.float32)),
            "frame_index": pa.array(np.concatenate([np.arange(k) for k in n])),
            "episode_index": pa.array(np.repeat(np.arange(first, first + len(group)), n)),
            "index": pa.array(np.arange(index, index + sum(n))),
            "task_index": pa.array(np.zeros(sum(n), np.int64)),
        }
        index += sum(n)
        path = root / "data" / "chunk-000" / f"file-{file:03d}.parquet"
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(columns), path)


def write_bags(root: Path, eps: list[Episode], per_file: int) -> None:
    for bag, first in enumerate(range(0, len(eps), per_file)):
        write_episodes(root / f"bag_{bag:03d}", eps[first:first + per_file], "dial",
                       first_episode_index=first)


def measure(command: list[str]) -> dict[str, float]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
           "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    done = subprocess.run([sys.executable, "-c", MEASURE, *command], env=env, capture_output=True, text=True,
                          check=True)
    rc, seconds, cpu, peak_kib = done.stdout.split()
    if rc != "0":
        raise RuntimeError(f"{' '.join(command)} exited {rc}: {done.stderr}")
    return {"seconds": float(seconds), "cpu_seconds": float(cpu), "peak_mib": int(peak_kib) / 1024}


def run(size: int, frames: int, per_file: int, work: Path, bags: bool) -> dict[str, Any]:
    eps = episodes(size, frames)
    write_dataset(work / f"dataset_{size}", eps, per_file)
    checkpoint = str(shipped_checkpoint("dial"))
    segment = [sys.executable, "-m", "ompn_ros.cli.segment", "--checkpoint", checkpoint]
    doc: dict[str, Any] = {"episodes": size, "frames": size * frames,
                           "dataset": measure([*segment, "--dataset", str(work / f"dataset_{size}"),
                                               "--out", str(work / f"out_dataset_{size}")])}
    if bags:
        write_bags(work / f"bags_{size}", eps, per_file)
        doc["bags"] = measure([*segment, "--bags", str(work / f"bags_{size}"), "--domain", "dial",
                               "--jobs", "1", "--out", str(work / f"out_bags_{size}")])
        doc["dataset_over_bags_time"] = doc["dataset"]["seconds"] / doc["bags"]["seconds"]
        doc["dataset_over_bags_cpu"] = doc["dataset"]["cpu_seconds"] / doc["bags"]["cpu_seconds"]
    rows = (work / f"out_dataset_{size}" / "segments.csv").read_text().count("\n") - 1
    doc["segments"] = rows
    return doc


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="100,1000", help="dataset sizes in episodes")
    parser.add_argument("--frames", type=int, default=500, help="frames per episode")
    parser.add_argument("--per-file", type=int, default=100, help="episodes per frame file and per bag")
    parser.add_argument("--bags-at", type=int, default=None, help="compare with bags at this size (default: "
                        "the largest)")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    compare = args.bags_at or max(sizes)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_lerobot_") as tmp:
        for size in sizes:
            start = time.perf_counter()
            results.append(run(size, args.frames, args.per_file, Path(tmp), bags=size == compare))
            results[-1]["bench_seconds"] = time.perf_counter() - start
            print(json.dumps(results[-1]), flush=True)
    print(json.dumps({"frames_per_episode": args.frames, "per_file": args.per_file, "results": results},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
