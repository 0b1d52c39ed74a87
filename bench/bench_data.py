"""Benchmark of the data path: bag writing, raw rosbags reading, episode reading, cache loading.

Dial-shaped episodes (39-float observations, 9-float actions, subtask, joint states): per step 4
messages.  Reported as messages per second over every message in the bag; the spec target is an
episode reader within 3x of a raw ``rosbags`` read (``episode_over_raw_time`` <= 3).

    .venv/bin/python bench/bench_data.py [--quick]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ompn_ros import layout
from ompn_ros.data import Episode, ReaderSpec, load_arrays, read_episodes, write_episodes


def _episodes(n: int, steps: int, seed: int = 0) -> list[Episode]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        out.append(Episode(
            observations=rng.standard_normal((steps + 1, layout.DIAL.obs_dim)).astype(np.float32),
            actions=rng.standard_normal((steps, layout.DIAL.action_dim)).astype(np.float32),
            subtask=np.repeat(np.arange(4), steps // 4 + 1)[:steps].astype(np.int64),
            sketch=np.arange(4, dtype=np.int64), task="dial", seed=i,
            extras={"joint_position": rng.standard_normal((steps + 1, 9))},
        ))
    return out


def _best(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """Measure and print; returns name -> (value, unit)."""
    from rosbags.rosbag2 import Reader

    n_ep, steps, repeats = (20, 100, 2) if quick else (150, 100, 3)
    episodes = _episodes(n_ep, steps)
    spec = ReaderSpec.for_domain("dial")
    results: dict[str, tuple[float, str]] = {}
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bench_data_"))
    try:
        for storage in ("mcap", "sqlite3"):
            bag = tmp / storage

            def write(bag: Path = bag, storage: str = storage) -> None:
                shutil.rmtree(bag, ignore_errors=True)
                write_episodes(bag, episodes, "dial", storage=storage)

            t_write = _best(write, repeats)
            with Reader(bag) as reader:
                n_msgs = reader.message_count

            def raw_read(bag: Path = bag) -> None:
                with Reader(bag) as reader:
                    for _ in reader.messages():
                        pass

            t_raw = _best(raw_read, repeats)
            t_read = _best(lambda bag=bag: read_episodes(bag, spec=spec), repeats)
            result = read_episodes(bag, spec=spec)
            assert len(result.episodes) == n_ep
            cache_dir = tmp / f"cache_{storage}"
            load_arrays(bag, spec=spec, cache_dir=cache_dir)
            t_cache = _best(lambda bag=bag, c=cache_dir: load_arrays(bag, spec=spec, cache_dir=c), repeats)
            res = {
                f"{storage}_write": (n_msgs / t_write, "msg/s"),
                f"{storage}_raw_read": (n_msgs / t_raw, "msg/s"),
                f"{storage}_episode_read": (n_msgs / t_read, "msg/s"),
                f"{storage}_episode_over_raw_time": (t_read / t_raw, "x"),
                f"{storage}_cache_hit_load": (t_cache * 1e3, "ms"),
            }
            results.update(res)
            rows.append((storage, n_msgs, *(v for v, _ in res.values())))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"data path: {n_ep} dial episodes x {steps} steps (best of {repeats})")
    print(f"{'storage':8} {'messages':>9} {'write msg/s':>12} {'raw read msg/s':>15} "
          f"{'episode read msg/s':>19} {'episode/raw time':>17} {'cache hit ms':>13}")
    for storage, n, w, r, e, ratio, c in rows:
        print(f"{storage:8} {n:9d} {w:12,.0f} {r:15,.0f} {e:19,.0f} {ratio:17.2f} {c:13.1f}")
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    run(quick=parser.parse_args().quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
