"""Exponential moving average (Polyak averaging) of a policy's weights, for evaluation and export."""

from __future__ import annotations

import copy

import torch


class WeightAverage:
    """An averaged copy of ``module``: ``avg ← d·avg + (1 − d)·θ`` after every update.

    The decay warms up as ``d = min(decay, (1 + i) / (10 + i))`` at iteration ``i`` (the schedule
    TensorFlow's ``ExponentialMovingAverage`` uses with ``num_updates``), so the average forgets the
    initial weights within the first few dozen updates.  Buffers (the observation normalisation) are
    copied, not averaged.  The schedule depends on the iteration only, so a resumed run reaches the
    same average as an uninterrupted one.
    """

    def __init__(self, module: torch.nn.Module, decay: float) -> None:
        if not 0.0 < decay < 1.0:
            raise ValueError(f"WeightAverage decay must be in (0, 1), got {decay!r}")
        self.decay = decay
        self.module = copy.deepcopy(module)
        self.module.requires_grad_(False)

    def decay_at(self, iteration: int) -> float:
        return min(self.decay, (1.0 + iteration) / (10.0 + iteration))

    @torch.no_grad()
    def update(self, module: torch.nn.Module, iteration: int) -> None:
        """Move the average towards ``module``'s weights after update number ``iteration`` (1-based)."""
        weight = 1.0 - self.decay_at(iteration)
        for avg, param in zip(self.module.parameters(), module.parameters(), strict=True):
            avg.lerp_(param.detach(), weight)
        for avg_buf, buf in zip(self.module.buffers(), module.buffers(), strict=True):
            avg_buf.copy_(buf)
