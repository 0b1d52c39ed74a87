"""Benchmark: end-to-end trainer throughput on Craft-shaped synthetic data (batch 256).

One iteration = collate 256 whole episodes (1075 features, ~24 steps + done) + teacher-forced
forward + loss + backward + clip + Adam step, i.e. :func:`ompn_ros.train.trainer.train_step` with
the Craft paper model (n = 3, m = 128).  Frames = valid rows including the done step.  The authors'
code measured ~3 000 frames/s (1.97 s/iteration) on this machine with 2 threads (docs/craft.md §7.3).

Run: ``.venv/bin/python bench/bench_train.py [--quick]``.
"""

from __future__ import annotations

import sys
import time

import torch


def _measure(threads: int, iterations: int, batch_size: int = 256) -> tuple[float, float, float]:
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.model.policy import OMPNPolicy
    from ompn_ros.train.batching import collate
    from ompn_ros.train.config import TrainConfig
    from ompn_ros.train.synthetic import CRAFT_ACTION_DIM, CRAFT_OBS_DIM, make_dataset
    from ompn_ros.train.trainer import train_step

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    episodes = make_dataset("craft_shaped", 2 * batch_size, seed=0)
    config = OMPNConfig(
        obs_dim=CRAFT_OBS_DIM,
        action_type="discrete",
        action_dim=CRAFT_ACTION_DIM,
        n_slots=3,
        slot_size=128,
        memory_update="code",
    )
    cfg = TrainConfig(lr=1e-3, batch_size=batch_size, progress=False, threads=threads)
    policy = OMPNPolicy(config)
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    batches = [episodes[i : i + batch_size] for i in range(0, len(episodes), batch_size)]
    train_step(policy, optimizer, batches[0], config, cfg)  # warm-up
    frames = 0
    started = time.perf_counter()
    for it in range(iterations):
        stats = train_step(policy, optimizer, batches[it % len(batches)], config, cfg)
        frames += int(stats["global_valid"])
    elapsed = time.perf_counter() - started
    collate_started = time.perf_counter()
    for it in range(iterations):
        collate(batches[it % len(batches)], "discrete", CRAFT_ACTION_DIM)
    collate_s = (time.perf_counter() - collate_started) / iterations
    return frames / elapsed, elapsed / iterations, collate_s


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """Measure; returns name -> (value, unit)."""
    iterations = 3 if quick else 10
    results: dict[str, tuple[float, str]] = {}
    for threads in (1,) if quick else (1, 2):
        fps, s_per_it, collate_s = _measure(threads, iterations)
        results[f"train_frames_per_s_{threads}thr"] = (fps, "frames/s")
        results[f"train_iteration_s_{threads}thr"] = (s_per_it, "s/iteration")
        results[f"train_collate_ms_{threads}thr"] = (collate_s * 1e3, "ms/batch")
    print(f"{'metric':<34}{'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<34}{value:>12.3f}  {unit}")
    return results


if __name__ == "__main__":
    run(quick="--quick" in sys.argv[1:])
