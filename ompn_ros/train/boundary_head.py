"""Fitting the boundary head (:mod:`ompn_ros.detect.head`) and choosing its decoding on validation.

``ompn_train`` calls :func:`fit_and_choose` at the end of training when the bags are labelled
(docs/design.md#boundary-head): the head learns, on every step of the training episodes, the
probability that step ``t - j`` ended a subtask (binary cross-entropy per lag ``j``, Adam); then the
lag, threshold, gap and ``peak`` of its decoding are chosen on the validation episodes for the best
alignment, then F1@1, then the shorter lag.  The OMPN itself does not change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from ompn_ros.data.episode import Episode
from ompn_ros.detect.head import BoundaryHead, decoded_steps, windowed
from ompn_ros.detect.online import HEAD_MODE, DetectorConfig
from ompn_ros.detect.tune import Metrics, delay_stats, score_predictions
from ompn_ros.metrics import alignment_counts, f1_with_tolerance

WINDOW = 8
"""Steps the head reads (docs/design.md#boundary-head)."""
HIDDEN = 64
EPOCHS = 40
MAX_HEAD_LAG = 6
"""The longest lag: the delay budget of docs/design.md#delay-budget."""
THETAS = tuple(round(0.05 * i, 2) for i in range(1, 20))
GAPS = (1, 2, 3, 4, 6, 8)


def targets(bounds: np.ndarray, length: int, max_lag: int) -> np.ndarray:
    """``[T, max_lag + 1]``: 1 where step ``t - j`` is an inner boundary (the last step is not one)."""
    y = np.zeros((length, max_lag + 1), dtype=np.float32)
    for b in np.asarray(bounds, dtype=np.int64):
        if b >= length - 1:
            continue
        for j in range(min(max_lag + 1, length - b)):
            y[b + j, j] = 1.0
    return y


def _stored(a: np.ndarray) -> np.ndarray:
    """``a`` rounded to float32, as the head's file keeps it (the rule is chosen on what the node runs)."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def train_head(outputs: Sequence[np.ndarray], bounds: Sequence[np.ndarray], seed: int, *,
               window: int = WINDOW, hidden: int = HIDDEN, epochs: int = EPOCHS,
               max_lag: int = MAX_HEAD_LAG) -> BoundaryHead:
    """The head trained on every step of the episodes ``outputs`` ``[T, F]`` with boundaries ``bounds``."""
    torch.manual_seed(seed)
    cat = np.concatenate([windowed(np.asarray(x, dtype=np.float64), window) for x in outputs])
    mean, std = _stored(cat.mean(0)), _stored(cat.std(0) + 1e-6)
    net = torch.nn.Sequential(torch.nn.Linear(cat.shape[1], hidden), torch.nn.ReLU(),
                              torch.nn.Linear(hidden, hidden), torch.nn.ReLU(),
                              torch.nn.Linear(hidden, max_lag + 1))
    z = torch.from_numpy(((cat - mean) / std).astype(np.float32))
    ys = [targets(b, len(x), max_lag) for x, b in zip(outputs, bounds, strict=True)]
    y = torch.from_numpy(np.concatenate(ys))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3, weight_decay=1e-4)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        for idx in torch.randperm(len(z), generator=gen).split(256):
            loss = torch.nn.functional.binary_cross_entropy_with_logits(net(z[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    layers = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights = tuple((m.weight.detach().double().numpy().T.copy(), m.bias.detach().double().numpy().copy())
                    for m in layers)
    return BoundaryHead(weights, mean, std, window, cat.shape[1] // window, episodes=len(outputs))


def score_rule(rows: Sequence[np.ndarray], episodes: Sequence[Episode], config: DetectorConfig,
               peak: bool) -> Metrics:
    """F1, alignment and delays of the head's decoding ``config`` over its probabilities ``rows``."""
    decoded = [decoded_steps(r, config, peak) for r in rows]
    preds = [np.array(steps, dtype=np.int64) for steps, _ in decoded]
    return {**score_predictions(preds, episodes),
            **delay_stats(preds, [ep.boundaries for ep in episodes], [when for _, when in decoded])}


@dataclass(frozen=True)
class HeadChoice:
    """The fitted head (its ``peak`` chosen), the decoding chosen and its validation figures."""

    head: BoundaryHead
    config: DetectorConfig
    metrics: Metrics


def choose_on_rows(rows: Sequence[np.ndarray], val_eps: Sequence[Episode]
                   ) -> tuple[DetectorConfig, bool, Metrics]:
    """The decoding of probabilities ``rows`` ``[T, max_lag + 1]`` with the best validation alignment,
    then F1@1, then the shorter lag: its config, its ``peak`` and its figures."""
    best: tuple[tuple[float, float, int], DetectorConfig, bool] | None = None
    seen: dict[tuple[int, tuple[int, ...]], tuple[int, int, float]] = {}
    for lag in range(1, rows[0].shape[1]):
        for theta in THETAS:
            for gap in GAPS:
                for peak in (False, True):
                    config = DetectorConfig(high=theta, mode=HEAD_MODE, lag=lag, min_segment_length=gap)
                    align, f1 = _choosing_figures(rows, val_eps, config, peak, seen)
                    key = (round(align, 6), round(f1, 6), -lag)
                    if best is None or key > best[0]:
                        best = (key, config, peak)
    if best is None:
        raise ValueError("choose_on_rows needs rows of at least two lags")
    return best[1], best[2], score_rule(rows, val_eps, best[1], best[2])


def _choosing_figures(rows: Sequence[np.ndarray], val_eps: Sequence[Episode], config: DetectorConfig,
                      peak: bool, seen: dict[tuple[int, tuple[int, ...]], tuple[int, int, float]]
                      ) -> tuple[float, float]:
    """The alignment and F1@1 that :func:`score_rule` gives the decoding ``config``, from each episode's
    figures (``seen``: by episode and decoded steps; most rules of the grid decode most episodes alike)."""
    correct = total = 0
    f1s = []
    for i, (r, ep) in enumerate(zip(rows, val_eps, strict=True)):
        steps = tuple(decoded_steps(r, config, peak)[0])
        got = seen.get((i, steps))
        if got is None:
            pred = np.array(steps, dtype=np.int64)
            c, n = alignment_counts(pred, np.asarray(ep.subtask), "authors")
            got = seen[(i, steps)] = (c, n, f1_with_tolerance(pred, ep.boundaries, 1).f1)
        correct, total = correct + got[0], total + got[1]
        f1s.append(got[2])
    return correct / total, float(np.mean(f1s))


def choose_rule(head: BoundaryHead, val_outputs: Sequence[np.ndarray], val_eps: Sequence[Episode]
                ) -> HeadChoice:
    """:func:`choose_on_rows` on the head's probabilities over the validation episodes."""
    config, peak, metrics = choose_on_rows([head.probabilities(x) for x in val_outputs], val_eps)
    return HeadChoice(replace(head, peak=peak, rule=config), config, metrics)


def fit_and_choose(train_outputs: Sequence[np.ndarray], train_eps: Sequence[Episode],
                   val_outputs: Sequence[np.ndarray], val_eps: Sequence[Episode], seed: int) -> HeadChoice:
    """The head trained on the labelled training episodes, its decoding chosen on the validation ones."""
    head = train_head(train_outputs, [ep.boundaries for ep in train_eps], seed)
    return choose_rule(head, val_outputs, val_eps)


__all__ = ["EPOCHS", "HIDDEN", "MAX_HEAD_LAG", "WINDOW", "HeadChoice", "choose_on_rows", "choose_rule",
           "fit_and_choose", "score_rule", "targets", "train_head"]
