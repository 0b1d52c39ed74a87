"""Figures of the reproduction: π over time on held-out episodes with the true, online and offline
boundaries (like Figures 4-5 and 9 of Lu et al., ICLR 2021)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lab.scoring import Evaluation, offline_boundaries
from ompn_ros.data.episode import Episode
from ompn_ros.plotting import plot_episode


def save_figures(
    domain: str, setting: str, test: Sequence[Episode], run: Evaluation, out: Path, count: int = 3
) -> list[str]:
    """Plot the first ``count`` test episodes of ``run`` into ``out``; returns the file paths."""
    paths = []
    for i, (ep, p_hat, replay) in enumerate(zip(test, run.p_hat, run.replays)):
        if i >= count:
            break
        k = len(ep.boundaries)
        offline = offline_boundaries(domain, p_hat, k)
        path = out / f"{domain}_{setting}_episode{i}.png"
        plot_episode(
            path,
            replay.pi,
            replay.pi_end,
            replay.scores,
            true_boundaries=ep.boundaries.tolist(),
            detected_boundaries=replay.boundary_steps.tolist(),
            offline_boundaries=list(offline),
            title=f"{domain} {setting}, held-out episode {i} ({ep.task}, {ep.length} steps)",
        )
        paths.append(str(path))
    return paths
