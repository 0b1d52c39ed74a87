"""Tiny synthetic hierarchical tasks for tests, smoke runs and benchmarks.

* **Discrete corridor** (Craft-like): an agent on a 1-D corridor of ``corridor`` cells visits a
  sequence of ``n_goals`` goal cells; each subtask is "walk to the goal, then USE".  Actions
  ``0 = left, 1 = right, 2 = use`` (``DISCRETE_ACTION_DIM = 3``; the trainer adds ``done``).
  Observation = one-hot position + one-hot displayed goal cell (zeros after the last goal) + one
  flag per reached goal.  On arrival the display switches to the *next* goal and the reached flag is
  set, and the agent answers with USE; so every subtask boundary is one observation event at the
  USE step, which ends its subtask (ground truth as in Craft, where the authors' Top-K hits the USE
  step itself).  Had the display switched only after USE, the model would expand on two consecutive
  steps (arrival and goal switch) and Top-K would spend two of its K picks on one boundary.
* **Continuous reaching** (Dial-like): a point in the plane reaches a sequence of landmarks (fixed
  points on a circle) with a saturated proportional controller plus noise.  Action = 2-D velocity;
  observation = position, displayed landmark position, reached flags.  As in the discrete task the
  display switches on arrival and a "press" step (zero velocity) ends the subtask.
* ``craft_shaped``: the discrete corridor with observations zero-padded to 1075 features and the
  action space widened to Craft's 5 actions, for benchmarking the trainer at Craft sizes.

Sketch tokens are the goal cells (discrete, vocabulary ``corridor``) or landmark ids (continuous,
vocabulary ``N_LANDMARKS``).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.train.errors import SyntheticError

DISCRETE_ACTION_DIM = 3
LEFT, RIGHT, USE = 0, 1, 2
CONTINUOUS_ACTION_DIM = 2
N_LANDMARKS = 8
LANDMARK_RADIUS = 5.0
CRAFT_OBS_DIM = 1075
CRAFT_ACTION_DIM = 5

SyntheticKind = Literal["discrete", "continuous", "craft_shaped"]


def discrete_obs_dim(corridor: int, n_goals: int) -> int:
    """Feature size of the discrete corridor observation."""
    return 2 * corridor + n_goals


def _discrete_obs(pos: int, goal: int | None, done: int, corridor: int, n_goals: int) -> np.ndarray:
    obs = np.zeros(discrete_obs_dim(corridor, n_goals), dtype=np.float32)
    obs[pos] = 1.0
    if goal is not None:
        obs[corridor + goal] = 1.0
    obs[2 * corridor : 2 * corridor + done] = 1.0
    return obs


def generate_discrete_episode(
    seed: int,
    *,
    corridor: int = 8,
    n_goals: int = 4,
    min_dist: int = 2,
    obs_pad_to: int | None = None,
) -> Episode:
    """One expert episode of the discrete corridor task (see module docstring)."""
    if corridor < 2 * min_dist + 1 or n_goals < 1 or min_dist < 1:
        raise SyntheticError(
            f"corridor={corridor}, n_goals={n_goals}, min_dist={min_dist}: need n_goals >= 1, "
            "min_dist >= 1 and corridor >= 2*min_dist+1"
        )
    rng = np.random.default_rng(seed)
    pos = int(rng.integers(corridor))
    goals: list[int] = []
    here = pos
    for _ in range(n_goals):
        choices = [c for c in range(corridor) if abs(c - here) >= min_dist]
        here = int(rng.choice(choices))
        goals.append(here)
    observations, actions, labels = [], [], []
    for i, goal in enumerate(goals):
        while pos != goal:
            observations.append(_discrete_obs(pos, goal, i, corridor, n_goals))
            labels.append(i)
            action = RIGHT if goal > pos else LEFT
            actions.append(action)
            pos += 1 if action == RIGHT else -1
        # arrival: the display already shows the next goal and one more reached flag; the agent USEs
        upcoming = goals[i + 1] if i + 1 < n_goals else None
        observations.append(_discrete_obs(pos, upcoming, i + 1, corridor, n_goals))
        labels.append(i)
        actions.append(USE)
    observations.append(_discrete_obs(pos, None, n_goals, corridor, n_goals))
    obs = np.stack(observations)
    if obs_pad_to is not None:
        if obs_pad_to < obs.shape[1]:
            raise SyntheticError(f"obs_pad_to={obs_pad_to} is smaller than the feature size {obs.shape[1]}")
        obs = np.pad(obs, ((0, 0), (0, obs_pad_to - obs.shape[1])))
    return Episode(
        observations=obs,
        actions=np.asarray(actions, dtype=np.int64),
        subtask=np.asarray(labels, dtype=np.int64),
        sketch=np.asarray(goals, dtype=np.int64),
        task="corridor",
        seed=seed,
        success=True,
    )


def landmarks() -> np.ndarray:
    """The ``N_LANDMARKS`` fixed 2-D goal points of the continuous task (a circle)."""
    angles = 2 * np.pi * np.arange(N_LANDMARKS) / N_LANDMARKS
    return (LANDMARK_RADIUS * np.stack([np.cos(angles), np.sin(angles)], axis=1)).astype(np.float32)


def _landmark_sequence(rng: np.random.Generator, n_goals: int) -> list[int]:
    """``n_goals`` landmark ids, consecutive ones at least two places apart on the circle (so
    subtasks take several steps)."""
    ids: list[int] = []
    previous = -1
    for _ in range(n_goals):
        choices = [
            j
            for j in range(N_LANDMARKS)
            if previous < 0 or min((j - previous) % N_LANDMARKS, (previous - j) % N_LANDMARKS) >= 2
        ]
        previous = int(rng.choice(choices))
        ids.append(previous)
    return ids


def _continuous_obs(pos: np.ndarray, goal: np.ndarray | None, reached: int, n_goals: int) -> np.ndarray:
    flags = np.zeros(n_goals, dtype=np.float32)
    flags[:reached] = 1.0
    g = np.zeros(2, dtype=np.float32) if goal is None else goal
    return np.concatenate([pos, g, flags]).astype(np.float32)


def _reach_action(
    goal: np.ndarray, pos: np.ndarray, max_speed: float, noise: float, rng: np.random.Generator
) -> np.ndarray:
    """The saturated proportional controller's velocity towards ``goal``, plus noise."""
    delta = goal - pos
    dist = float(np.linalg.norm(delta))
    action = delta if dist <= max_speed else delta * (max_speed / dist)
    return (action + rng.normal(0.0, noise, size=2)).astype(np.float32)


def generate_continuous_episode(
    seed: int,
    *,
    n_goals: int = 4,
    max_speed: float = 1.5,
    radius: float = 0.5,
    noise: float = 0.1,
    max_steps: int = 200,
) -> Episode:
    """One expert episode of the continuous reaching task (see module docstring).

    Positions are in metres-like units with landmarks on a circle of radius ``LANDMARK_RADIUS``;
    actions (velocities) are of order 1 so that the fixed-variance (0.6) Gaussian likelihood of the
    Dial head gives a useful training signal.  On arrival (within ``radius``) the display switches
    to the next landmark and the agent makes one "press" step (zero velocity plus noise), the last
    step of the subtask, like the USE step of the discrete task.
    """
    if n_goals < 1 or max_speed <= 0 or radius <= 0:
        raise SyntheticError(f"n_goals={n_goals}, max_speed={max_speed}, radius={radius} must be positive")
    rng = np.random.default_rng(seed)
    points = landmarks()
    ids = _landmark_sequence(rng, n_goals)
    pos = rng.uniform(-1.0, 1.0, size=2).astype(np.float32)
    observations: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    labels: list[int] = []
    for i, landmark in enumerate(ids):
        goal = points[landmark]
        while float(np.linalg.norm(goal - pos)) >= radius:
            if len(actions) >= max_steps:
                raise SyntheticError(f"continuous episode (seed {seed}) exceeded {max_steps} steps")
            observations.append(_continuous_obs(pos, goal, i, n_goals))
            labels.append(i)
            action = _reach_action(goal, pos, max_speed, noise, rng)
            actions.append(action)
            pos = (pos + action).astype(np.float32)
        upcoming = points[ids[i + 1]] if i + 1 < n_goals else None
        observations.append(_continuous_obs(pos, upcoming, i + 1, n_goals))
        labels.append(i)
        actions.append(rng.normal(0.0, noise, size=2).astype(np.float32))
    observations.append(_continuous_obs(pos, None, n_goals, n_goals))
    return Episode(
        observations=np.stack(observations),
        actions=np.stack(actions).astype(np.float32),
        subtask=np.asarray(labels, dtype=np.int64),
        sketch=np.asarray(ids, dtype=np.int64),
        task="reach",
        seed=seed,
        success=True,
    )


def make_dataset(
    kind: SyntheticKind, n_episodes: int, seed: int = 0, **options: int | float
) -> list[Episode]:
    """``n_episodes`` episodes of one synthetic task with seeds ``seed, seed + 1, …``."""
    if n_episodes < 1:
        raise SyntheticError(f"n_episodes must be >= 1, got {n_episodes}")
    if kind == "discrete":
        return [generate_discrete_episode(seed + i, **options) for i in range(n_episodes)]  # type: ignore[arg-type]
    if kind == "continuous":
        return [generate_continuous_episode(seed + i, **options) for i in range(n_episodes)]  # type: ignore[arg-type]
    if kind == "craft_shaped":
        opts = {"corridor": 10, "n_goals": 4, "min_dist": 3, **options}
        return [
            generate_discrete_episode(seed + i, obs_pad_to=CRAFT_OBS_DIM, **opts)  # type: ignore[arg-type]
            for i in range(n_episodes)
        ]
    raise SyntheticError(
        f"unknown synthetic kind {kind!r}; expected 'discrete', 'continuous' or 'craft_shaped'"
    )


def synthetic_spec(kind: SyntheticKind, **options: int) -> tuple[int, str, int, int]:
    """``(obs_dim, action_type, action_dim, sketch_vocab)`` of a synthetic task."""
    if kind == "discrete":
        corridor = int(options.get("corridor", 8))
        return (
            discrete_obs_dim(corridor, int(options.get("n_goals", 4))),
            "discrete",
            DISCRETE_ACTION_DIM,
            corridor,
        )
    if kind == "continuous":
        return 4 + int(options.get("n_goals", 4)), "continuous", CONTINUOUS_ACTION_DIM, N_LANDMARKS
    if kind == "craft_shaped":
        return CRAFT_OBS_DIM, "discrete", CRAFT_ACTION_DIM, int(options.get("corridor", 10))
    raise SyntheticError(
        f"unknown synthetic kind {kind!r}; expected 'discrete', 'continuous' or 'craft_shaped'"
    )
