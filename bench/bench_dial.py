"""Benchmark of the Dial domain: env step rate, real-time factor, expert demonstration rate and stats.

Usage: ``python bench/bench_dial.py [--quick]``.  ``run(quick)`` returns name -> (value, unit).
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from sim_nodes.dial.env import DialEnv
from sim_nodes.dial.expert import generate_episodes
from sim_nodes.dial.scene import FRAME_SKIP, TIMESTEP, TORQUE_SCALE


def _env_steps_per_second(n_steps: int) -> float:
    env = DialEnv()
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    for i in range(n_steps):
        hold = env.data.qfrc_bias[env.dm.dof_adr] / TORQUE_SCALE  # keeps the arm up, no contacts
        env.step(np.clip(hold + rng.normal(0.0, 0.05, 9), -1, 1))
        if (i + 1) % 200 == 0:
            env.reset(seed=i)
    return n_steps / (time.perf_counter() - start)


def _raw_mj_steps_per_second(n_steps: int) -> float:
    env = DialEnv()
    env.reset(seed=0)
    start = time.perf_counter()
    mujoco.mj_step(env.model, env.data, nstep=n_steps)
    return n_steps / (time.perf_counter() - start)


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    n_steps = 500 if quick else 5000
    n_eps = 10 if quick else 200
    env_rate = _env_steps_per_second(n_steps)
    mj_rate = _raw_mj_steps_per_second(n_steps * FRAME_SKIP)
    start = time.perf_counter()
    episodes = list(generate_episodes(n_eps, seed=0))
    wall = time.perf_counter() - start
    lengths = np.array([e.length for e in episodes])
    segments = np.concatenate([np.bincount(e.subtask) for e in episodes])
    return {
        "env_steps_per_s": (env_rate, "steps/s"),
        "real_time_factor": (env_rate * FRAME_SKIP * TIMESTEP, "sim s / wall s"),
        "mj_step_per_s_zero_ctrl": (mj_rate, "mj_step/s"),
        "expert_episodes_per_s": (n_eps / wall, "episodes/s"),
        "expert_steps_per_s": (lengths.sum() / wall, "steps/s"),
        "demo_success_rate": (float(np.mean([e.success for e in episodes])), "fraction"),
        "demo_first_try_rate": (float(np.mean([e.extras["attempt"] == 0 for e in episodes])), "fraction"),
        "demo_length_mean": (float(lengths.mean()), "steps"),
        "demo_length_std": (float(lengths.std()), "steps"),
        "demo_length_min": (float(lengths.min()), "steps"),
        "demo_length_max": (float(lengths.max()), "steps"),
        "demo_subtask_mean": (float(segments.mean()), "steps"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    results = run(quick=parser.parse_args().quick)
    width = max(len(k) for k in results)
    print(f"{'metric':<{width}}  {'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<{width}}  {value:>12.3f}  {unit}")


if __name__ == "__main__":
    main()
