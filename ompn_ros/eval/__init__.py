"""Closed-loop (free-run) evaluation of behaviour-cloned policies (ROS-free core + a ROS driver)."""

from ompn_ros.eval.closed_loop import (
    EVAL_SEED_BASE,
    ClosedLoopError,
    ClosedLoopReport,
    EpisodeResult,
    RandomAgent,
    ReplayAgent,
    eval_seeds,
    run_closed_loop,
    run_craft,
    run_dial,
)

__all__ = [
    "EVAL_SEED_BASE",
    "ClosedLoopError",
    "ClosedLoopReport",
    "EpisodeResult",
    "RandomAgent",
    "ReplayAgent",
    "eval_seeds",
    "run_closed_loop",
    "run_craft",
    "run_dial",
]
