"""Craft benchmark: env steps/s, expert episodes/s, 3×500 demos vs the authors' 16.3 s (docs/craft.md §7.2).

Run: ``.venv/bin/python bench/bench_craft.py`` (``--quick`` for a short run).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from sim_nodes.craft import PAPER_TASKS, CraftEnv, generate_episodes
from sim_nodes.craft.features import decode_compact, encode_compact

AUTHORS_FULL_S = 16.3  # 3×500 full-obs demos, authors' code on this machine (incl. ~3 s start-up, pickling)
AUTHORS_PARTIAL_S = 17.0


def _env_steps_per_s(n_steps: int) -> float:
    env = CraftEnv("makebed", full_obs=True)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 5, size=n_steps)
    env.reset(seed=0)
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def _demo_time(n_per_task: int, full_obs: bool) -> tuple[float, int]:
    start = time.perf_counter()
    steps = 0
    for i, task in enumerate(PAPER_TASKS):
        for ep in generate_episodes(n_per_task, task=task, full_obs=full_obs, seed=1000 + i):
            steps += ep.length
    return time.perf_counter() - start, steps


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    n = 100 if quick else 500
    results: dict[str, tuple[float, str]] = {}
    results["craft_env_steps_per_s"] = (_env_steps_per_s(5_000 if quick else 30_000), "steps/s")
    full_s, full_steps = _demo_time(n, True)
    partial_s, _ = _demo_time(n, False)
    results["craft_expert_full_episodes_per_s"] = (3 * n / full_s, "episodes/s")
    results["craft_expert_full_steps_per_s"] = (full_steps / full_s, "steps/s")
    results[f"craft_demo_full_3x{n}_s"] = (full_s, "s")
    results[f"craft_demo_partial_3x{n}_s"] = (partial_s, "s")
    if not quick:
        results["craft_demo_full_speedup_vs_authors"] = (AUTHORS_FULL_S / full_s, "x")
        results["craft_demo_partial_speedup_vs_authors"] = (AUTHORS_PARTIAL_S / partial_s, "x")
    eps = list(generate_episodes(50, task="makebed", seed=1))
    obs = np.concatenate([e.observations for e in eps])
    start = time.perf_counter()
    packed = encode_compact(obs)
    decode_compact(packed)
    results["craft_compact_roundtrip_rows_per_s"] = (len(obs) / (time.perf_counter() - start), "rows/s")
    results["craft_compact_bytes_per_row"] = (float(packed.shape[1]), "bytes (float32: 4300)")
    return results


def main() -> None:
    results = run(quick="--quick" in sys.argv)
    width = max(len(k) for k in results)
    print(f"{'metric':<{width}}  {'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<{width}}  {value:>12.2f}  {unit}")


if __name__ == "__main__":
    main()
