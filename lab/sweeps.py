"""The appendix sweeps of Lu et al., ICLR 2021: Top-K with a fixed K (Craft) and fixed thresholds
against the automatic one (Dial), on one checkpoint's held-out ``p_hat``.  O(|sweep| · Σ T)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect.offline import auto_threshold_boundaries, threshold_boundaries, top_k_boundaries
from ompn_ros.metrics import alignment_accuracy, mean_f1

Table = dict[str, dict[str, float]]


def k_sweep(
    p_hats: Sequence[np.ndarray], test: Sequence[Episode], ks: Sequence[int] = (2, 3, 4, 5, 6)
) -> Table:
    """Top-K precision/recall/F1 at tol 1 for fixed K (paper appendix K sweep)."""
    table = {}
    for k in ks:
        preds = [top_k_boundaries(p, k) for p in p_hats]
        res = mean_f1(preds, [ep.boundaries for ep in test], 1)
        table[f"K={k}"] = {"f1_tol1": res.f1, "precision_tol1": res.precision, "recall_tol1": res.recall}
    return table


def threshold_sweep(
    p_hats: Sequence[np.ndarray],
    test: Sequence[Episode],
    thresholds: Sequence[float] = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7),
) -> Table:
    """Alignment accuracy per fixed threshold and the automatic one (paper appendix, Dial)."""
    labels = [np.asarray(ep.subtask) for ep in test]
    table = {}
    for thr in thresholds:
        preds = [threshold_boundaries(p, thr, len(ep.boundaries)) for p, ep in zip(p_hats, test, strict=True)]
        table[f"{thr:.1f}"] = {"align": alignment_accuracy(preds, labels, variant="authors")}
    preds = [auto_threshold_boundaries(p, len(ep.boundaries))[0] for p, ep in zip(p_hats, test, strict=True)]
    table["auto"] = {"align": alignment_accuracy(preds, labels, variant="authors")}
    return table
