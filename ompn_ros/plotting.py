"""Plots of the expansion distribution over time with true and detected boundaries (paper Figs. 4-5).

Uses matplotlib's Agg backend (no display needed), imported on the first plot: a command that plots
nothing (a batch or dataset run) does not pay its import (about 0.3 s of CPU, ``bench/bench_batch_pool.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ompn_ros.atomic import atomic_write

if TYPE_CHECKING:
    from matplotlib.axes import Axes


def _pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (imported once, on the first plot)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_episode(
    path: str | Path,
    pi: np.ndarray,
    pi_end: np.ndarray,
    scores: np.ndarray,
    *,
    true_boundaries: Sequence[int] | None = None,
    detected_boundaries: Sequence[int] | None = None,
    offline_boundaries: Sequence[int] | None = None,
    high: float | None = None,
    low: float | None = None,
    title: str = "",
) -> Path:
    """Write a two-panel PNG of one episode and return its path.

    Top: stacked slot probabilities ``pi`` (``[T, n]``, lowest slot first) scaled by ``1 - pi_end``,
    with ``pi_end`` on top (together: ``p_hat``).  Bottom: the detector score (code-weighted
    pi_avg / n) with the thresholds.  Vertical lines: true boundaries (green, dashed), online
    detections (red), offline detections (blue, dotted).
    """
    pi = np.asarray(pi, dtype=np.float64)
    pi_end = np.asarray(pi_end, dtype=np.float64).reshape(-1)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    T = pi.shape[0]
    t = np.arange(T)
    plt = _pyplot()
    fig, (ax_pi, ax_s) = plt.subplots(2, 1, figsize=(max(6.0, min(18.0, T / 8)), 5.0), sharex=True)
    _draw_expansion(ax_pi, t, pi, pi_end)
    _draw_score(ax_s, t, scores, high, low)
    for ax in (ax_pi, ax_s):
        for b in true_boundaries or []:
            ax.axvline(b, color="green", ls="--", lw=1.0)
        for b in detected_boundaries or []:
            ax.axvline(b, color="red", lw=1.0, alpha=0.8)
        for b in offline_boundaries or []:
            ax.axvline(b, color="blue", ls=":", lw=1.0)
    _label_score_axis(ax_s, offline=offline_boundaries is not None)
    if title:
        ax_pi.set_title(title)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:  # whole or absent, like every output file (a full disk: one line naming the file)
        atomic_write(out, lambda handle: fig.savefig(handle, dpi=100, format=out.suffix.lstrip(".") or "png"))
    finally:
        plt.close(fig)
    return out


def _draw_expansion(ax: Axes, t: np.ndarray, pi: np.ndarray, pi_end: np.ndarray) -> None:
    """The top panel: ``p_hat`` stacked, slot 1 at the bottom and ``pi_end`` on top."""
    n = pi.shape[1]
    layers = [pi[:, i] * (1.0 - pi_end) for i in range(n)] + [pi_end]
    labels = [f"slot {i + 1}" for i in range(n)] + ["π_end"]
    ax.stackplot(t, *layers, labels=labels, step="mid", alpha=0.85)
    ax.set_ylim(0, 1)
    ax.set_ylabel("p̂ (expansion)")
    ax.legend(loc="upper left", fontsize=7, ncol=n + 1)


def _draw_score(ax: Axes, t: np.ndarray, scores: np.ndarray, high: float | None, low: float | None) -> None:
    """The bottom panel's score curve and the detector's thresholds."""
    ax.plot(t, scores, color="black", lw=1.2, label="score")
    if high is not None:
        ax.axhline(high, color="gray", ls="--", lw=0.8, label="high")
    if low is not None and high is not None and low != high:
        ax.axhline(low, color="gray", ls=":", lw=0.8, label="low")


def _label_score_axis(ax: Axes, *, offline: bool) -> None:
    """The bottom panel's limits, labels and legend (boundary line styles, then score and thresholds)."""
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("step")
    ax.set_ylabel("score")
    plt = _pyplot()
    handles = [
        plt.Line2D([], [], color="green", ls="--", label="true"),
        plt.Line2D([], [], color="red", label="online"),
    ]
    if offline:
        handles.append(plt.Line2D([], [], color="blue", ls=":", label="offline"))
    ax.legend(handles=handles + ax.get_legend_handles_labels()[0], loc="upper left", fontsize=7)
