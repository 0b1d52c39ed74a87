"""The in-memory episode: what environments produce, bags store and the trainer consumes."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

OBSERVATION_COPIES = "observation_copies"
"""``Episode.extras`` key: int ``[T + 1]``, how many times each observation message is published or written
(0 = dropped, 2 = duplicated; absent = once each).  The arrays of the episode stay complete."""

OBS_STAMPS = "obs_stamp_ns"
"""``Episode.extras`` key: int64 ``[T + 1]`` (or ``[T]``), the bag log stamp of each observation row's
message, in ns (the bag reader fills it; annotated bags and offline tables place their outputs there)."""

DONE_ACTION = -1
"""Marker meaning 'the done step' where an integer action is needed in generic code.

Discrete models map the done step to class index ``action_dim`` (Craft: 5)."""


@dataclass
class Episode:
    """One demonstration of ``T`` real steps.

    Attributes:
        observations: float32 ``[T + 1, obs_dim]``.  Row ``t < T`` is the observation before
            action ``t``; row ``T`` is the final observation, used for the appended 'done' step
            (paper Algorithm 1: the trajectory is extended with ``(s_{T+1}, done)``).
        actions: ``[T]`` int64 (discrete) or ``[T, action_dim]`` float32 (continuous).  The done
            step is *not* stored: the trainer appends it.
        subtask: int64 ``[T]`` ground-truth subtask ordinal (0-based) per real step, or ``None``.
            Step ``t`` carries the subtask it works on; the step that completes a subtask still
            carries that subtask (Craft: the USE step belongs to the subtask it completes).
        sketch: int64 ``[K]`` subtask ids of the task (weak supervision), or ``None``.
        task: task name ('makebed', 'dial', ...).
        seed: the seed that generated the episode, or -1 when unknown.
        success: whether the demonstrator finished the whole sketch.
        extras: optional per-step arrays (e.g. ``joint_position`` ``[T + 1, 9]``).
    """

    observations: np.ndarray
    actions: np.ndarray
    subtask: np.ndarray | None = None
    sketch: np.ndarray | None = None
    task: str = ""
    seed: int = -1
    success: bool = True
    extras: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.observations.ndim != 2:
            raise ValueError(
                f"Episode.observations must be 2-D [T+1, obs_dim], got shape {self.observations.shape}"
            )
        n = len(self.actions)
        if len(self.observations) != n + 1:
            raise ValueError(
                f"Episode has {n} actions but {len(self.observations)} observations; "
                "expected len(observations) == len(actions) + 1 (the final observation)"
            )
        if self.subtask is not None and len(self.subtask) != n:
            raise ValueError(f"Episode.subtask has length {len(self.subtask)}, expected {n}")

    @property
    def length(self) -> int:
        """Number of real steps ``T`` (without the done step)."""
        return len(self.actions)

    @property
    def boundaries(self) -> np.ndarray:
        """Ground-truth boundaries: the last step index of every subtask (always ends at T-1)."""
        if self.subtask is None:
            raise ValueError(f"episode of task '{self.task}' (seed {self.seed}) has no subtask labels")
        return boundaries_from_labels(self.subtask)


def observation_copies(episode: Episode) -> np.ndarray:
    """How many times each observation row is published (``extras[OBSERVATION_COPIES]``, default once)."""
    copies = episode.extras.get(OBSERVATION_COPIES)
    if copies is None:
        return np.ones(len(episode.observations), dtype=np.int64)
    copies = np.asarray(copies, dtype=np.int64)
    if copies.shape != (len(episode.observations),) or np.any((copies < 0) | (copies > 2)):
        raise ValueError(f"extras['{OBSERVATION_COPIES}'] of episode seed {episode.seed} must be "
                         f"{len(episode.observations)} counts in 0..2, got shape {copies.shape}")
    return copies


def boundaries_from_labels(labels: np.ndarray) -> np.ndarray:
    """Indices ``t`` where ``labels[t] != labels[t + 1]``, plus the last index."""
    labels = np.asarray(labels)
    if labels.size == 0:
        return np.zeros(0, dtype=np.int64)
    change = np.flatnonzero(labels[1:] != labels[:-1])
    return np.concatenate([change, [labels.size - 1]]).astype(np.int64)
