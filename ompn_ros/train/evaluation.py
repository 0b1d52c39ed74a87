"""Teacher-forced evaluation: loss, expansion distributions and task-decomposition metrics.

Used by the trainer's periodic validation and by the reproduction pipeline on held-out episodes.
Detection uses ``K`` = the episode's number of ground-truth boundaries unless ``k`` is given (the
paper's K-sweep tables).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch

from ompn_ros.data.episode import Episode
from ompn_ros.detect.head import head_outputs
from ompn_ros.detect.offline import (
    auto_threshold_boundaries,
    constrained_top_k_boundaries,
    threshold_boundaries,
    top_k_boundaries,
)
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.train.batching import collate
from ompn_ros.train.device import batch_to, device_of
from ompn_ros.train.errors import EvaluationError


def _scores(prefix: str, preds: list[np.ndarray], episodes: Sequence[Episode]) -> dict[str, float]:
    gts = [ep.boundaries for ep in episodes]
    labels = [np.asarray(ep.subtask) for ep in episodes]
    out: dict[str, float] = {}
    for tol in (0, 1):
        res = mean_f1(preds, gts, tol)
        out[f"{prefix}f1_tol{tol}"] = res.f1
        out[f"{prefix}precision_tol{tol}"] = res.precision
        out[f"{prefix}recall_tol{tol}"] = res.recall
    out[f"{prefix}align"] = alignment_accuracy(preds, labels, variant="authors")
    out[f"{prefix}align_strict"] = alignment_accuracy(preds, labels, variant="strict")
    return out


def decomposition_metrics(
    p_hats: Sequence[np.ndarray],
    episodes: Sequence[Episode],
    *,
    k: int | None = None,
    thresholds: Sequence[float] = (),
    primary: str = "topk",
    min_length: int = 2,
) -> dict[str, float]:
    """Metrics of the offline detectors on per-episode ``p_hat`` ``[T, n+1]`` (real steps only).

    Keys: ``topk_*`` (Top-K, docs/craft.md §5.2), ``topkc_*`` (Top-K constrained to subtasks of at
    least ``min_length`` steps ending at the episode's last step,
    :func:`~ompn_ros.detect.offline.constrained_top_k_boundaries`), ``auto_*`` (automatic
    threshold, paper Algorithm 2, plus ``auto_fallback_rate``), and ``thr<θ>_*`` for every fixed
    threshold in ``thresholds`` (paper Algorithm 1), each with ``f1_tol0/1``, ``precision_tol0/1``,
    ``recall_tol0/1``, ``align`` (authors' decoding) and ``align_strict``.  The unprefixed
    ``f1_tol0``, ``f1_tol1``, ``align`` and ``align_strict`` repeat the ``primary`` detector
    (``'topk'`` or ``'auto'``; the paper's detectors).
    """
    if len(p_hats) != len(episodes):
        raise EvaluationError(f"got {len(p_hats)} p_hat sequences for {len(episodes)} episodes")
    if not episodes:
        raise EvaluationError("decomposition metrics need at least one episode")
    for i, (p_hat, ep) in enumerate(zip(p_hats, episodes, strict=True)):
        if ep.subtask is None:
            raise EvaluationError(f"episode #{i} (task '{ep.task}', seed {ep.seed}) has no subtask labels")
        if len(p_hat) != ep.length:
            raise EvaluationError(
                f"episode #{i}: p_hat has {len(p_hat)} rows but the episode has {ep.length} steps"
            )
    ks = [k if k is not None else len(ep.boundaries) for ep in episodes]
    topk = [top_k_boundaries(p, kk) for p, kk in zip(p_hats, ks, strict=True)]
    auto_runs = [auto_threshold_boundaries(p, kk) for p, kk in zip(p_hats, ks, strict=True)]
    constrained = [constrained_top_k_boundaries(p, kk, min_length=min_length)
                   for p, kk in zip(p_hats, ks, strict=True)]
    out = _scores("topk_", topk, episodes)
    out.update(_scores("topkc_", constrained, episodes))
    out.update(_scores("auto_", [b for b, _ in auto_runs], episodes))
    out["auto_fallback_rate"] = float(np.mean([a.fallback for _, a in auto_runs]))
    for theta in thresholds:
        preds = [threshold_boundaries(p, theta, kk) for p, kk in zip(p_hats, ks, strict=True)]
        out.update(_scores(f"thr{theta:g}_", preds, episodes))
    if primary not in ("topk", "auto"):
        raise EvaluationError(f"primary detector must be 'topk' or 'auto', got {primary!r}")
    for key in ("f1_tol0", "f1_tol1", "align", "align_strict"):
        out[key] = out[f"{primary}_{key}"]
    return out


MIN_LENGTH_CANDIDATES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32)
"""Grid of the constrained Top-K's ``min_length``, in steps (held-out subtasks last 1–51 steps in
Craft, median 6, and 23–125 in Dial)."""


def tune_min_length(
    p_hats: Sequence[np.ndarray],
    episodes: Sequence[Episode],
    candidates: Sequence[int] = MIN_LENGTH_CANDIDATES,
) -> tuple[int, dict[int, float]]:
    """The ``min_length`` of the constrained Top-K with the best alignment on ``episodes``.

    Meant for a run's validation episodes (never the test ones).  Returns ``(best, {candidate:
    alignment})``; ties go to the smaller ``min_length`` (the weaker assumption).
    """
    if not candidates:
        raise EvaluationError("tune_min_length needs at least one candidate min_length")
    if any(ep.subtask is None for ep in episodes):
        raise EvaluationError("tune_min_length needs episodes with subtask labels")
    labels = [np.asarray(ep.subtask) for ep in episodes]
    if len(p_hats) != len(episodes):
        raise EvaluationError(f"got {len(p_hats)} p_hat sequences for {len(episodes)} episodes")
    scores: dict[int, float] = {}
    for length in sorted(set(int(c) for c in candidates)):
        preds = [constrained_top_k_boundaries(p, len(ep.boundaries), min_length=length)
                 for p, ep in zip(p_hats, episodes, strict=True)]
        scores[length] = alignment_accuracy(preds, labels, variant="authors")
    best = max(scores, key=lambda length: (scores[length], -length))
    return best, scores


def _teacher_forced(policy: OMPNPolicy, episodes: Sequence[Episode], bptt: int, batch_size: int
                    ) -> Iterator[tuple[Sequence[Episode], Any, Any]]:
    """``(episodes, batch, outputs)`` per chunk of ``batch_size`` episodes, in evaluation mode."""
    if not episodes:
        raise EvaluationError("evaluation needs at least one episode")
    config = policy.config
    was_training = policy.training
    policy.eval()
    use_sketch = config.sketch_mode != "none"
    device = device_of(policy)
    try:
        with torch.no_grad():
            for start in range(0, len(episodes), batch_size):
                chunk = episodes[start : start + batch_size]
                batch = batch_to(collate(chunk, config.action_type, config.action_dim, use_sketch), device)
                yield chunk, batch, policy.forward_sequence(batch.obs, batch.mask, batch.sketch, bptt=bptt)
    finally:
        policy.train(was_training)


def teacher_forced_p_hat(
    policy: OMPNPolicy,
    episodes: Sequence[Episode],
    *,
    bptt: int = 64,
    batch_size: int = 64,
    no_done_loss: bool = False,
) -> tuple[list[np.ndarray], dict[str, float]]:
    """Per-episode ``p_hat`` for the real steps and the loss statistics (done step included)."""
    config = policy.config
    total_loss = total_acc = total_valid = 0.0
    p_hats: list[np.ndarray] = []
    for chunk, batch, out in _teacher_forced(policy, episodes, bptt, batch_size):
        _, stats = bc_loss(
            out, batch.actions, batch.mask, batch.done_mask, config, no_done_loss=no_done_loss,
            action_scale=policy.action_scale(),
        )
        n_valid = float(batch.valid_steps)
        total_loss += stats["loss"] * n_valid
        total_acc += stats.get("accuracy", 0.0) * n_valid
        total_valid += n_valid
        p_hat = out.p_hat.cpu().numpy()
        for i, ep in enumerate(chunk):
            p_hats.append(p_hat[i, : ep.length].astype(np.float64))
    stats_out = {"loss": total_loss / total_valid}
    if config.action_type == "discrete":
        stats_out["accuracy"] = total_acc / total_valid
    return p_hats, stats_out


def teacher_forced_outputs(
    policy: OMPNPolicy, episodes: Sequence[Episode], *, bptt: int = 64, batch_size: int = 64
) -> list[np.ndarray]:
    """Per-episode boundary-head inputs ``[T, n + 1 + A]`` for the real steps: ``p_hat`` beside the
    action output (:func:`~ompn_ros.detect.head.head_outputs`), as the node's stepper gives them."""
    discrete = policy.config.action_type == "discrete"
    rows: list[np.ndarray] = []
    for chunk, _, out in _teacher_forced(policy, episodes, bptt, batch_size):
        both = head_outputs(out.p_hat.cpu().numpy(), out.action_out.float().cpu().numpy(), discrete)
        rows += [both[i, : ep.length] for i, ep in enumerate(chunk)]
    return rows


def evaluate(
    policy: OMPNPolicy,
    episodes: Sequence[Episode],
    *,
    bptt: int = 64,
    batch_size: int = 64,
    no_done_loss: bool = False,
    keep_p_hat: bool = True,
    k: int | None = None,
    thresholds: Sequence[float] = (),
    min_length: int = 2,
) -> dict[str, Any]:
    """Teacher-forced evaluation of ``policy`` on whole ``episodes`` (each from the initial memory).

    Returns ``loss`` (mean ``−log p'`` per valid step including the done step), ``accuracy``
    (discrete: argmax of p' incl. done), ``n_episodes``, ``n_steps``, ``p_hat`` (list of ``[T, n+1]``
    arrays for the real steps, if ``keep_p_hat``) and, when every episode has subtask labels, the
    :func:`decomposition_metrics` with the domain's primary detector: Top-K for discrete actions
    (Craft), automatic threshold for continuous ones (Dial).
    """
    p_hats, stats = teacher_forced_p_hat(
        policy, episodes, bptt=bptt, batch_size=batch_size, no_done_loss=no_done_loss
    )
    result: dict[str, Any] = {
        **stats,
        "n_episodes": len(episodes),
        "n_steps": int(sum(ep.length for ep in episodes)),
    }
    if all(ep.subtask is not None for ep in episodes):
        primary = "topk" if policy.config.action_type == "discrete" else "auto"
        result.update(decomposition_metrics(
            p_hats, episodes, k=k, thresholds=thresholds, primary=primary, min_length=min_length
        ))
    if keep_p_hat:
        result["p_hat"] = p_hats
    return result
