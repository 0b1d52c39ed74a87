"""Held-out scores of one checkpoint: offline, constrained and online detectors.

* Offline (Lu et al., ICLR 2021, §3.3): Top-K (Algorithm 1) for Craft, the automatic threshold
  (Algorithm 2) for Dial, with K = the true number of boundaries, on teacher-forced ``p_hat``.
* Constrained Top-K: Top-K restricted to subtasks of at least ``min_length`` steps ending at the
  episode's last step, ``min_length`` tuned on the run's validation episodes.
* Online: the causal detector of ``ompn_node`` replayed through the ``StreamingSegmenter``, with the
  package's shipped settings and with settings tuned on the validation episodes; and the duration
  decoder (mode 'hsmm', lag ``DURATION_LAG``) fitted and tuned on the validation episodes within each
  mean delay of :data:`DURATION_DELAYS` (``online_hsmm_d<delay>_*``), scored on the same replays.

Validation episodes tune; test episodes only score.  Cost: O(Σ T) model steps per checkpoint plus
the detector grid search, O(|grid| · Σ T_val).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.app.replay import check_finite, compare_detectors, replay_all
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import Episode
from ompn_ros.detect.choose import duration_detector, replay_config
from ompn_ros.detect.defaults import DURATION_LAG
from ompn_ros.detect.grid import scores_from_p_hats
from ompn_ros.detect.offline import auto_threshold_boundaries, top_k_boundaries
from ompn_ros.detect.online import DURATION_MODES, HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.detect.params_file import load_detector_yaml, write_node_config
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.detect.tune import DEFAULT_OBJECTIVE, Metrics, choose_on_replays, score_online
from ompn_ros.model.load import build_stepper
from ompn_ros.paths import config_file
from ompn_ros.segmenter import ReplayResult
from ompn_ros.train.evaluation import evaluate, teacher_forced_p_hat, tune_min_length

METRIC_KEYS = ("align", "align_strict", "f1_tol0", "f1_tol1", "precision_tol1", "recall_tol1")
"""Offline metrics of the domain's paper detector, reported under their own names."""
CONSTRAINED_KEYS = ("align", "f1_tol1", "f1_tol0")
"""Metrics of the constrained Top-K reported beside the paper's detector (``constrained_<key>``)."""
DEFAULT_MIN_LENGTH = 2
"""min_length of the constrained Top-K when a run has no validation episodes to tune it on."""
TRAINING_CELLS = ("train_seconds", "frames_per_second")
"""Result cells that only training produces (kept from the previous results by --reevaluate)."""
DURATION_DELAYS = (2, 4, 6, 8, 10, 12, 15)
"""Mean delays (steps) within which the duration decoder is tuned and scored (``online_hsmm_d<delay>_*``)."""


def offline_boundaries(domain: str, p_hat: np.ndarray, k: int) -> np.ndarray:
    """The paper's offline detector of ``domain`` with ``k`` subtasks: Top-K on Craft, the automatic
    threshold on Dial."""
    return top_k_boundaries(p_hat, k) if domain == "craft" else auto_threshold_boundaries(p_hat, k)[0]


@dataclass(frozen=True)
class DetectorTuning:
    """The online detector chosen on validation episodes and what it measured there."""

    config: DetectorConfig
    measured_on_val: dict[str, Metrics]
    n_val: int

    def write(self, path: Path, domain: str, what: str) -> Path:
        """The chosen settings as an ``ompn_node`` params file."""
        return write_node_config(
            path, domain, self.config, self.measured_on_val, f"the {self.n_val} validation episodes {what}"
        )


@dataclass
class Evaluation:
    """One checkpoint scored on the test episodes (``row``: metric name -> value)."""

    row: dict[str, float]
    p_hat: list[np.ndarray]
    val_p_hat: list[np.ndarray] = field(default_factory=list)
    replays: list[ReplayResult] = field(default_factory=list)
    tuning: DetectorTuning | None = None
    val: list[Episode] = field(default_factory=list)
    checkpoint: Path | None = None


def tuned_min_length(val_p_hats: Sequence[np.ndarray], val: Sequence[Episode]) -> int:
    """The constrained Top-K's ``min_length`` chosen on validation episodes (never the test ones)."""
    return tune_min_length(val_p_hats, val)[0] if val else DEFAULT_MIN_LENGTH


def duration_metrics(
    replays: Sequence[ReplayResult], test: Sequence[Episode], val_p_hats: Sequence[np.ndarray],
    val: Sequence[Episode], delays: Sequence[float] = DURATION_DELAYS,
) -> dict[str, float]:
    """``online_hsmm_d<delay>_*`` on the test ``replays``: the duration decoder fitted on the validation
    labels and its threshold tuned there for alignment within each mean ``delay`` (teacher-forced
    validation scores, equal to the streamed ones to 1e-5).
    O(len(delays) · thresholds · Σ T_val · K · n²)."""
    val_scores = scores_from_p_hats(val_p_hats)
    row: dict[str, float] = {}
    for delay in delays:
        tuned = duration_detector(val_scores, [ep.boundaries for ep in val], DURATION_LAG, delay)
        if tuned is None:  # no model (fewer than two subtasks per episode): no figures
            return row
        found = score_online(replays, test, tuned.config, tuned.model)
        row.update({f"online_hsmm_d{delay:g}_{k}": v for k, v in found.items()})
        row[f"online_hsmm_d{delay:g}_threshold"] = tuned.config.high
    return row


HEAD_MODES = (HEAD_MODE, HEAD_DURATION_MODE)
"""The modes that decode with a boundary head."""


def _overrides_detector(node_config: Path) -> bool:
    """Whether an ompn_node params file sets a ``detector_*`` key (it then overrides the checkpoint's)."""
    text = node_config.read_text(encoding="utf-8")
    return any(line.strip().startswith("detector_") for line in text.splitlines())


def online_metrics(
    test: Sequence[Episode], domain: str, stepper: Any, val: Sequence[Episode] = ()
) -> tuple[dict[str, float], list[ReplayResult], DetectorTuning | None]:
    """The causal detector replayed through ``StreamingSegmenter`` (as live) on ``test``.

    Two detector settings are scored on the same replays: the shipped one of ``domain``
    (``online_shipped_*``) and one tuned for this checkpoint on ``val`` by the grid search of
    :mod:`ompn_ros.detect.tune` with the domain's default objective (``online_*``).  Without
    ``val`` the shipped setting is reported under both names.  The shipped setting is the one the node
    runs with: the shipped checkpoint's ``detector.json`` (the node configs hold no ``detector_*`` key
    unless they override it); one of mode 'hsmm' decodes with that checkpoint's duration model, one of
    mode 'head' with its boundary head.
    """
    settings = load_detector_settings(shipped_checkpoint(domain))
    shipped, model, head = settings.online, settings.duration_model, settings.head
    if _overrides_detector(config_file(f"ompn_node_{domain}.yaml")):
        shipped = load_detector_yaml(config_file(f"ompn_node_{domain}.yaml"))
    if shipped.mode not in DURATION_MODES:
        model = None
    if shipped.mode not in HEAD_MODES:
        head = None
    configs = {"shipped": shipped}
    tuning = None
    if val:
        on_replays = replay_all(stepper, val, replay_config())  # the search reads their scores only
        check_finite(on_replays, val)
        tuned, _, on_val = choose_on_replays(on_replays, val, objective=DEFAULT_OBJECTIVE[domain])
        configs["tuned"] = tuned
        tuning = DetectorTuning(tuned, on_val, len(val))
    replays = replay_all(stepper, test, configs.get("tuned", shipped), model, head)
    scores = compare_detectors(stepper, test, configs, replays=replays, duration_model=model, head=head)
    row = {f"online_shipped_{k}": v for k, v in scores["shipped"].items()}
    row.update({f"online_{k}": v for k, v in scores["tuned" if tuning else "shipped"].items()})
    return row, replays, tuning


def evaluate_policy(
    domain: str, policy: Any, test: list[Episode], val: Sequence[Episode] = (), online: bool = True
) -> Evaluation:
    """Offline (Top-K for Craft, automatic threshold for Dial; and the constrained Top-K with its
    ``min_length`` tuned on ``val``) and, with ``online``, online metrics on ``test``."""
    val_p_hats = teacher_forced_p_hat(policy, list(val))[0] if val else []
    min_length = tuned_min_length(val_p_hats, val)
    offline = evaluate(policy, test, keep_p_hat=True, min_length=min_length)
    row: dict[str, float] = {"align_acc": offline["align"]}
    primary = "topk_" if domain == "craft" else "auto_"
    row.update({k: offline[primary + k] for k in METRIC_KEYS})
    row.update({f"constrained_{k}": offline[f"topkc_{k}"] for k in CONSTRAINED_KEYS})
    row["constrained_min_length"] = float(min_length)
    result = Evaluation(row, offline["p_hat"], list(val_p_hats), val=list(val))
    if online:
        online_row, result.replays, result.tuning = online_metrics(test, domain, build_stepper(policy), val)
        row.update(online_row)
        if val:
            row.update(duration_metrics(result.replays, test, val_p_hats, val))
    return result


def aggregate(rows: Sequence[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per metric, mean and (population) std over the finite values of ``rows``, and ``n`` = rows."""
    out: dict[str, dict[str, float]] = {}
    for key in rows[0]:
        values = np.asarray([r[key] for r in rows], dtype=np.float64)
        finite = values[np.isfinite(values)]
        mean = float(finite.mean()) if finite.size else float("nan")
        std = float(finite.std()) if finite.size else float("nan")
        out[key] = {"mean": mean, "std": std, "n": len(rows)}
    return out
