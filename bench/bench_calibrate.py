"""Benchmark: label-free calibration of the online detector for a Craft checkpoint (target ≤ 60 s).

The shipped Craft checkpoint replays validation-sized sets of generated expert episodes through
the streaming segmenter (as ``ompn_node`` would see them), then
:func:`ompn_ros.detect.calibrate.calibrate_label_free` searches the 216-setting grid against the
reference ``ompn_train`` uses (the constrained Top-K with K pooled per task from the automatic
threshold, paper Algorithms 1-2), and :func:`tune_on_labels` does the same
against the labels for comparison.  240 episodes = a Craft run's validation split (20 % of the
1200-episode training pool).  Episode generation is not timed.

Run: ``.venv/bin/python bench/bench_calibrate.py [--quick]``.
"""

from __future__ import annotations

import sys
import time


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """Measure; returns name -> (value, unit)."""
    import numpy as np

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.detect.calibrate import tune_on_labels
    from ompn_ros.detect.choose import calibrate_without_labels
    from ompn_ros.model.load import stepper_from_checkpoint
    from ompn_ros.segmenter import StreamingSegmenter
    from ompn_ros.stream.replay import replay_episode
    from sim_nodes.craft import PAPER_TASKS, generate_episode

    n = 60 if quick else 240
    tasks = list(PAPER_TASKS)
    episodes = [generate_episode(30_000 + i, task=tasks[i % len(tasks)]) for i in range(n)]
    stepper = stepper_from_checkpoint(shipped_checkpoint("craft"))
    started = time.perf_counter()
    segmenter = StreamingSegmenter(stepper)
    replays = [replay_episode(segmenter, ep, include_done_step=True) for ep in episodes]
    replayed = time.perf_counter()
    calibrate_without_labels([r.p_hat for r in replays], episodes, "discrete", [r.scores for r in replays])
    calibrated = time.perf_counter()
    tune_on_labels([r.scores for r in replays], [np.asarray(ep.subtask) for ep in episodes], "f1")
    tuned = time.perf_counter()
    steps = sum(ep.length + 1 for ep in episodes)
    results = {
        f"calibrate_label_free_total_s_{n}ep": (calibrated - started, "s"),
        f"calibrate_replay_s_{n}ep": (replayed - started, "s"),
        f"calibrate_grid_s_{n}ep": (calibrated - replayed, "s"),
        f"tune_on_labels_grid_s_{n}ep": (tuned - calibrated, "s"),
        "calibrate_replay_steps_per_s": (steps / (replayed - started), "steps/s"),
    }
    print(f"{'metric':<40}{'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<40}{value:>12.3f}  {unit}")
    return results


if __name__ == "__main__":
    run(quick="--quick" in sys.argv[1:])
