"""``ompn_segment --tune``: choose the online detector on replayed episodes and store the choice.

The threshold detector is grid-searched (:func:`ompn_ros.detect.tune.choose_on_replays`), the 'hsmm'
duration detector is fitted beside it (:func:`ompn_ros.train.detector.duration_detector`) and the
online one picked between them (:func:`ompn_ros.train.detector.pick_online`); a checkpoint's
boundary head, with the decoding chosen with it, runs instead when it aligns better on the same
episodes, and the duration decoder over that head (mode 'head_hsmm', its threshold tuned as the
duration decoder's) when it aligns better still (:func:`ompn_ros.train.detector.prefer`); see
docs/design.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ompn_ros.app import replay
from ompn_ros.data.episode import Episode
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.detect.tune import (
    DEFAULT_OBJECTIVE,
    Metrics,
    choose_on_replays,
    default_grid,
    score_online,
    write_node_config,
)
from ompn_ros.train.detector import duration_detector, pick_online, prefer, tune_head_duration


@dataclass
class Tuned:
    """The chosen online detector, its metrics, the comparison with the other detectors, both
    detectors' validation figures and the duration model of an 'hsmm' choice (else None)."""

    objective: str
    best: DetectorConfig
    metrics: Metrics
    comparison: dict[str, Metrics]
    figures: dict[str, float]
    model: DurationModel | None

    def doc(self) -> dict[str, Any]:
        """What ``ompn_segment --tune`` prints."""
        return {"best": self.best.to_dict(), "metrics": self.metrics, "comparison": self.comparison,
                "choice": self.figures}


def tune_detector(policy: Any, episodes: Sequence[Episode], objective: str | None, domain: str | None,
                  lag: int, max_delay: float, long_subtasks: bool = False,
                  head: BoundaryHead | None = None) -> Tuned:
    """Replay ``episodes`` once and choose the online detector maximising ``objective`` (none: the
    domain's, F1 without a domain); the 'hsmm' detector of ``lag`` may cost ``max_delay`` mean steps;
    ``head``: the checkpoint's boundary head, a candidate with its stored decoding."""
    objective = objective or DEFAULT_OBJECTIVE.get(domain or "", "f1")
    replays = replay.replay_all(policy, episodes, default_grid()[0])
    replay.check_finite(replays, episodes)
    threshold, metrics, comparison = choose_on_replays(replays, episodes, objective=objective,
                                                       long_subtasks=long_subtasks)
    duration = duration_detector([r.scores for r in replays], [ep.boundaries for ep in episodes], lag,
                                 max_delay)
    model = None if duration is None else duration.model
    best, figures = pick_online(threshold, metrics, duration)
    if head is not None and head.rule is not None:
        alone = score_online(replays, episodes, head.rule, None, head)
        best = prefer(best, figures, HEAD_MODE, head.rule, alone)
        if duration is not None:
            outputs = [r.outputs for r in replays if r.outputs is not None]
            both = tune_head_duration(duration.model, head, outputs, episodes, lag, max_delay)
            best = prefer(best, figures, HEAD_DURATION_MODE, both.config, both.metrics)
    if best is not threshold:  # 'online' names what runs: the duration decoder or the head
        metrics = score_online(replays, episodes, best, model, head)
        comparison = {"online": metrics, "online_threshold": comparison.pop("online"), **comparison}
    return Tuned(objective, best, metrics, comparison, figures, model)


def write_tuned(tuned: Tuned, params_file: str, domain: str | None, checkpoint: str, source: str) -> Path:
    """Write the choice as an ``ompn_node`` params file and into the checkpoint's detector.json (tuned on
    ``source``); returns the detector.json written."""
    objective = tuned.objective
    provenance = f"ompn_segment --tune on {source}, objective {objective}, online mode {tuned.best.mode}"
    write_node_config(params_file, domain or "", tuned.best, tuned.comparison,
                      f"{source}, objective {objective}, checkpoint {checkpoint}")
    measured = {**tuned.metrics, **tuned.figures}
    return replay.store_tuned(checkpoint, tuned.best, measured, provenance, tuned.model)
