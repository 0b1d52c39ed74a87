"""Ensembles of checkpoints scored on held-out episodes: the members' ``p_hat`` averaged.

Averaging the expansion distributions before decoding keeps the paper's detectors unchanged (Top-K,
Algorithm 1; automatic threshold, Algorithm 2; Lu et al., ICLR 2021, §3.3).  Two kinds are reported:
the seeds of a setting averaged offline, and per seed an ensemble of members trained on the seed's
split (written as an ensemble checkpoint that ``ompn_node`` loads, and also scored online).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lab.scoring import (
    CONSTRAINED_KEYS,
    DEFAULT_MIN_LENGTH,
    Evaluation,
    online_metrics,
    tuned_min_length,
)
from lab.spec import ReproduceError
from ompn_ros.data.episode import Episode
from ompn_ros.model.ensemble import write_ensemble
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.train.evaluation import decomposition_metrics

ENSEMBLE_ONLINE_KEYS = ("online_f1_tol1", "online_align_strict", "online_delay_mean")
"""Online cells reported for an ensemble (with the detector tuned on its validation split)."""


def average_p_hats(p_hats_per_model: Sequence[Sequence[np.ndarray]]) -> list[np.ndarray]:
    """Episode by episode, the mean ``p_hat`` of several checkpoints (an ensemble's expansion
    distribution).  O(M · Σ T) for M models."""
    if len(p_hats_per_model) < 2:
        raise ReproduceError("an ensemble needs the checkpoints of at least 2 models")
    return [np.mean(np.stack(per_episode), axis=0) for per_episode in zip(*p_hats_per_model, strict=True)]


def ensemble_scores(
    domain: str,
    p_hats_per_model: Sequence[Sequence[np.ndarray]],
    test: Sequence[Episode],
    min_length: int = DEFAULT_MIN_LENGTH,
) -> dict[str, float]:
    """The domain's offline detector (Top-K for Craft, automatic threshold for Dial) and the
    constrained Top-K (``min_length``) on the test ``p_hat`` averaged over several checkpoints."""
    mean = average_p_hats(p_hats_per_model)
    scores = decomposition_metrics(
        mean, test, primary="topk" if domain == "craft" else "auto", min_length=min_length
    )
    out = {"align_acc": scores["align"], "f1_tol1": scores["f1_tol1"], "f1_tol0": scores["f1_tol0"]}
    out.update({f"constrained_{k}": scores[f"topkc_{k}"] for k in CONSTRAINED_KEYS})
    return out


def member_ensemble_row(
    domain: str, member_runs: Sequence[Evaluation], test: Sequence[Episode], ensemble_dir: Path
) -> dict[str, float]:
    """One seed's ensemble, written as an ensemble checkpoint (``ensemble_dir/ensemble.json``, what
    ``ompn_node`` loads) and scored on ``test``: offline, the members' test ``p_hat`` averaged with
    the constrained Top-K's ``min_length`` tuned on their shared validation split; online, the
    ensemble stepper replayed as live with the causal detector tuned on that split (written to
    ``ensemble_dir/ompn_node_<domain>.yaml``)."""
    val = member_runs[0].val
    min_length = tuned_min_length(average_p_hats([r.val_p_hat for r in member_runs]) if val else [], val)
    row = ensemble_scores(domain, [r.p_hat for r in member_runs], test, min_length)
    row["constrained_min_length"] = float(min_length)
    checkpoints = [r.checkpoint for r in member_runs if r.checkpoint is not None]
    write_ensemble(
        ensemble_dir, checkpoints, {"constrained_min_length": min_length, "offline_metrics": dict(row)}
    )
    online, _, tuning = online_metrics(test, domain, stepper_from_checkpoint(ensemble_dir), val)
    row.update({k: v for k, v in online.items() if k in ENSEMBLE_ONLINE_KEYS})
    if tuning is not None:
        tuning.write(
            ensemble_dir / f"ompn_node_{domain}.yaml", domain, f"shared by the ensemble {ensemble_dir}"
        )
    return row


def majority_min_length(rows: Sequence[dict[str, float]]) -> int:
    """The constrained ``min_length`` most seeds chose (ties: the smallest)."""
    lengths = [int(r["constrained_min_length"]) for r in rows]
    return min(set(lengths), key=lambda v: (-lengths.count(v), v))
