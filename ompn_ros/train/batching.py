"""Collate whole episodes into padded tensors with the appended done step (paper Algorithm 1).

An episode of ``T`` real steps becomes ``T + 1`` rows: rows ``0..T−1`` carry the demonstrated
actions, row ``T`` carries the final observation and the *done* action (paper §3.3: the trajectory
is extended with ``(s_{T+1}, done)``).  Discrete: the done row's action is index ``action_dim``.
Continuous: the done row's action is zeros and ``done_mask`` marks it.  Shorter episodes are
zero-padded to the longest one in the batch; ``mask`` is True on the ``T + 1`` valid rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from ompn_ros.data.episode import Episode
from ompn_ros.train.errors import BatchError

ObsNormMode = Literal["none", "maxabs"]
TEACHER_P_HAT = "teacher_p_hat"
"""``Episode.extras`` key of a distillation target ``[T, n+1]`` (:mod:`ompn_ros.train.distill`)."""


@dataclass(frozen=True)
class ObsNormalization:
    """Per-feature observation normalisation ``(s − mean) / scale``."""

    mean: np.ndarray
    scale: np.ndarray

    def apply(self, obs: np.ndarray) -> np.ndarray:
        return ((obs - self.mean) / self.scale).astype(np.float32)


def obs_normalization(episodes: Sequence[Episode], mode: ObsNormMode) -> ObsNormalization:
    """Statistics from the training split.

    ``'maxabs'`` (ompn_dial, docs/dial.md §4.1): mean over all observation rows and scale = the max
    absolute raw value per feature (the code calls it "std"); features that are always 0 get scale 1.
    ``'none'``: mean 0, scale 1 (Craft's one-hot features are used raw).

    One pass over the episodes with float64 accumulators (per-feature sum, row count, max
    absolute value): O(rows · D) time, O(D) memory, so episodes memory-mapped from the cache are
    read page by page and never copied into one array.
    """
    if not episodes:
        raise BatchError("cannot compute observation statistics from an empty episode list")
    dim = episodes[0].observations.shape[1]
    if mode == "none":
        return ObsNormalization(np.zeros(dim, np.float32), np.ones(dim, np.float32))
    if mode != "maxabs":
        raise BatchError(f"obs_norm must be 'none' or 'maxabs', got {mode!r}")
    total = np.zeros(dim, np.float64)
    scale = np.zeros(dim, np.float64)
    rows = 0
    for i, ep in enumerate(episodes):
        obs = ep.observations
        if obs.ndim != 2 or obs.shape[1] != dim:
            raise BatchError(f"episode #{i} has observations of shape {obs.shape}, the first has {dim} "
                             "features")
        if len(obs):
            total += obs.sum(axis=0, dtype=np.float64)
            np.maximum(scale, np.abs(obs).max(axis=0), out=scale)
            rows += len(obs)
    if rows == 0:
        raise BatchError("cannot compute observation statistics: the episodes hold no observation")
    scale[scale == 0] = 1.0
    return ObsNormalization((total / rows).astype(np.float32), scale.astype(np.float32))


def action_normalization(episodes: Sequence[Episode]) -> tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean and standard deviation of the continuous actions of ``episodes`` (the
    training split), for ``action_norm='standard'``; a constant dimension gets std 1.  O(steps x A)."""
    if not episodes:
        raise BatchError("cannot compute action statistics from an empty episode list")
    stacked = np.concatenate([np.asarray(e.actions, np.float64) for e in episodes], axis=0)
    if stacked.ndim != 2:
        raise BatchError(f"action_norm='standard' needs [T, A] continuous actions, got {stacked.shape[1:]}")
    mean, std = stacked.mean(axis=0), stacked.std(axis=0)
    std[~(std > 1e-8)] = 1.0
    return mean.astype(np.float32), std.astype(np.float32)


@dataclass
class Batch:
    """A padded batch of ``B`` episodes, ``L = max(T) + 1`` rows.

    Attributes:
        obs: float32 ``[B, L, D]`` (raw; the policy applies its normalisation).
        actions: int64 ``[B, L]`` (discrete, done = ``action_dim``) or float32 ``[B, L, A]``.
        mask: bool ``[B, L]``, True on the ``T + 1`` valid rows of each episode.
        done_mask: bool ``[B, L]``, True only on row ``T`` (the appended done step).
        sketch: int64 ``[B, K]`` sketch ids (the episodes' ids; -1 = padding) or None.
        lengths: int64 ``[B]`` real steps ``T`` per episode (without the done step).
        teacher_p_hat: float32 ``[B, L, n+1]`` distillation targets of the real steps (zeros on the
            done step and padding) when every episode carries ``extras[TEACHER_P_HAT]``, else None
            (:mod:`ompn_ros.train.distill`).
    """

    obs: torch.Tensor
    actions: torch.Tensor
    mask: torch.Tensor
    done_mask: torch.Tensor
    sketch: torch.Tensor | None
    lengths: torch.Tensor
    teacher_p_hat: torch.Tensor | None = None

    @property
    def size(self) -> int:
        return int(self.obs.shape[0])

    @property
    def valid_steps(self) -> int:
        """Number of valid rows including the done steps (the loss denominator)."""
        return int(self.mask.sum())


def _describe(ep: Episode, index: int) -> str:
    return f"episode #{index} (task '{ep.task}', seed {ep.seed})"


def _checked_actions(ep: Episode, index: int, action_type: str, action_dim: int) -> np.ndarray:
    """``ep``'s ``T`` actions as the batch stores them: int ids in ``[0, action_dim)`` (discrete) or
    float32 ``[T, action_dim]`` (continuous); a :class:`BatchError` naming the episode otherwise."""
    if action_type == "discrete":
        acts = np.asarray(ep.actions)
        if acts.ndim != 1 or not np.issubdtype(acts.dtype, np.integer):
            raise BatchError(
                f"{_describe(ep, index)} has actions of shape {acts.shape} / {acts.dtype}; expected int [T]"
            )
        if acts.size and (acts.min() < 0 or acts.max() >= action_dim):
            raise BatchError(f"{_describe(ep, index)} has action ids outside [0, {action_dim})")
        return acts
    acts = np.asarray(ep.actions, dtype=np.float32)
    if acts.shape != (ep.length, action_dim):
        raise BatchError(
            f"{_describe(ep, index)} has actions of shape {acts.shape}; expected ({ep.length}, {action_dim})"
        )
    return acts


def _sketches(episodes: Sequence[Episode]) -> torch.Tensor:
    """The episodes' sketch ids (the domain's ids, >= 0) padded with -1 to the longest: ``[B, S]``."""
    sketches = []
    for i, ep in enumerate(episodes):
        if ep.sketch is None:
            raise BatchError(f"{_describe(ep, i)} has no sketch but the model uses sketches")
        sketch = np.asarray(ep.sketch, dtype=np.int64)
        if sketch.size and sketch.min() < 0:
            raise BatchError(f"{_describe(ep, i)} has negative sketch ids {sketch.tolist()}")
        sketches.append(sketch)
    padded = np.full((len(sketches), max(len(s) for s in sketches)), -1, dtype=np.int64)
    for i, sketch in enumerate(sketches):
        padded[i, : len(sketch)] = sketch
    return torch.from_numpy(padded)


def collate(
    episodes: Sequence[Episode],
    action_type: str,
    action_dim: int,
    use_sketch: bool = False,
) -> Batch:
    """Pad ``episodes`` into a :class:`Batch` with the appended done step.

    Raises :class:`BatchError` when an episode's observation size, action type/size or sketch
    length does not match the rest of the batch.
    """
    if not episodes:
        raise BatchError("cannot collate an empty list of episodes")
    if action_type not in ("discrete", "continuous"):
        raise BatchError(f"action_type must be 'discrete' or 'continuous', got {action_type!r}")
    dim = episodes[0].observations.shape[1]
    rows = max(e.length for e in episodes) + 1
    size = len(episodes)
    obs = np.zeros((size, rows, dim), dtype=np.float32)
    mask = np.zeros((size, rows), dtype=bool)
    done = np.zeros((size, rows), dtype=bool)
    if action_type == "discrete":
        actions = np.zeros((size, rows), dtype=np.int64)
    else:
        actions = np.zeros((size, rows, action_dim), dtype=np.float32)
    for i, ep in enumerate(episodes):
        t = ep.length
        if ep.observations.shape[1] != dim:
            raise BatchError(
                f"{_describe(ep, i)} has {ep.observations.shape[1]} observation features, expected {dim}"
            )
        if t < 1:
            raise BatchError(f"{_describe(ep, i)} has no steps")
        obs[i, : t + 1] = ep.observations
        mask[i, : t + 1] = True
        done[i, t] = True
        actions[i, :t] = _checked_actions(ep, i, action_type, action_dim)
        if action_type == "discrete":
            actions[i, t] = action_dim
    return Batch(
        obs=torch.from_numpy(obs),
        actions=torch.from_numpy(actions),
        mask=torch.from_numpy(mask),
        done_mask=torch.from_numpy(done),
        sketch=_sketches(episodes) if use_sketch else None,
        lengths=torch.tensor([e.length for e in episodes], dtype=torch.int64),
        teacher_p_hat=_teacher_targets(episodes, rows),
    )


def _teacher_targets(episodes: Sequence[Episode], rows: int) -> torch.Tensor | None:
    """The episodes' ``extras[TEACHER_P_HAT]`` ``[T, n+1]`` padded to ``[B, rows, n+1]``; None unless
    every episode has one."""
    targets = [ep.extras.get(TEACHER_P_HAT) for ep in episodes]
    if any(t is None for t in targets):
        return None
    width = np.asarray(targets[0]).shape[-1]
    out = np.zeros((len(episodes), rows, width), dtype=np.float32)
    for i, (ep, target) in enumerate(zip(episodes, targets, strict=True)):
        arr = np.asarray(target, dtype=np.float32)
        if arr.shape != (ep.length, width):
            raise BatchError(f"{_describe(ep, i)} has a {TEACHER_P_HAT} of shape {arr.shape}; expected "
                             f"({ep.length}, {width})")
        out[i, : ep.length] = arr
    return torch.from_numpy(out)


def split_train_val(n_episodes: int, val_ratio: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded shuffle, then the first ``round(val_ratio · N)`` indices go to validation.

    At least one episode stays in training; validation may be empty when ``val_ratio`` is 0.
    """
    if not 0.0 <= val_ratio < 1.0:
        raise BatchError(f"val_ratio must be in [0, 1), got {val_ratio}")
    if n_episodes < 1:
        raise BatchError("need at least one episode to split")
    order = np.random.default_rng([seed, 0x5EED]).permutation(n_episodes)
    n_val = min(round(val_ratio * n_episodes), n_episodes - 1)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def epoch_batches(n_train: int, batch_size: int, seed: int, epoch: int) -> list[np.ndarray]:
    """Index batches of one epoch: a seeded reshuffle cut into consecutive chunks of whole episodes.

    The permutation depends only on ``(seed, epoch)`` so a resumed run sees the same batches.
    """
    order = np.random.default_rng([seed, epoch]).permutation(n_train)
    return [order[i : i + batch_size] for i in range(0, n_train, batch_size)]
