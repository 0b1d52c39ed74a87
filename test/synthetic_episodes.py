"""Synthetic Craft- and Dial-shaped episodes and exact episode equality, shared by the data tests."""

from __future__ import annotations

import numpy as np

from ompn_ros import layout
from ompn_ros.data.episode import Episode


def craft_episode(i: int, steps: int, rng: np.random.Generator) -> Episode:
    """A random Craft-shaped episode (obs 1075, discrete actions 0..4, 3 subtasks)."""
    return Episode(
        observations=rng.random((steps + 1, layout.CRAFT.obs_dim), dtype=np.float32),
        actions=rng.integers(0, layout.CRAFT.action_dim, steps).astype(np.int64),
        subtask=np.sort(rng.integers(0, 3, steps)).astype(np.int64),
        sketch=np.asarray([2, 5, 7], dtype=np.int64),
        task="makebed",
        seed=1000 + i,
        success=i % 3 != 2,
    )


def dial_episode(i: int, steps: int, rng: np.random.Generator) -> Episode:
    """A random Dial-shaped episode (obs 39, actions [T, 9], 4 subtasks, joint extras)."""
    return Episode(
        observations=rng.standard_normal((steps + 1, layout.DIAL.obs_dim)).astype(np.float32),
        actions=rng.standard_normal((steps, layout.DIAL.action_dim)).astype(np.float32),
        subtask=np.sort(rng.integers(0, 4, steps)).astype(np.int64),
        sketch=rng.permutation(10)[:4].astype(np.int64),
        task="dial",
        seed=2000 + i,
        success=True,
        extras={
            "joint_position": rng.standard_normal((steps + 1, 9)),
            "joint_velocity": rng.standard_normal((steps + 1, 9)),
            "joint_names": [f"jaco_joint_{k}" for k in range(9)],
        },
    )


def make_episodes(domain: str, n: int, seed: int = 0, min_steps: int = 5,
                  max_steps: int = 30) -> list[Episode]:
    rng = np.random.default_rng(seed)
    make = craft_episode if domain == "craft" else dial_episode
    return [make(i, int(rng.integers(min_steps, max_steps + 1)), rng) for i in range(n)]


def assert_same_episode(a: Episode, b: Episode, *, joints: bool = False) -> None:
    """Exact equality of everything a bag stores."""
    np.testing.assert_array_equal(a.observations, b.observations)
    assert a.observations.dtype == b.observations.dtype == np.float32
    np.testing.assert_array_equal(a.actions, b.actions)
    assert a.actions.dtype == b.actions.dtype
    if a.subtask is None:
        assert b.subtask is None
    else:
        assert b.subtask is not None
        np.testing.assert_array_equal(a.subtask, b.subtask)
    if a.sketch is None:
        assert b.sketch is None
    else:
        assert b.sketch is not None
        np.testing.assert_array_equal(a.sketch, b.sketch)
    assert (a.task, a.seed, a.success) == (b.task, b.seed, b.success)
    if joints:
        for key in ("joint_position", "joint_velocity"):
            np.testing.assert_array_equal(a.extras[key], b.extras[key])
        assert list(a.extras["joint_names"]) == list(b.extras["joint_names"])
