"""``ompn_segment --tune``: replay the episodes once, let :func:`ompn_ros.detect.choose.choose_on_replayed`
choose the online detector on the replays (the grid's threshold detector, the 'hsmm' duration
decoder, a checkpoint's boundary head and the duration decoder over it; docs/design.md), and store
the choice.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ompn_ros.app import replay
from ompn_ros.data.episode import Episode
from ompn_ros.detect.choose import Tuned, choose_on_replayed, replay_config, tuning_objective
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.params_file import write_node_config


def tune_detector(policy: Any, episodes: Sequence[Episode], objective: str | None, domain: str | None,
                  lag: int, max_delay: float, long_subtasks: bool = False,
                  head: BoundaryHead | None = None) -> Tuned:
    """Replay ``episodes`` once and choose the online detector maximising ``objective`` (none: the
    domain's, F1 without a domain); the 'hsmm' detector of ``lag`` may cost ``max_delay`` mean steps;
    ``head``: the checkpoint's boundary head, a candidate with its stored decoding."""
    replays = replay.replay_all(policy, episodes, replay_config())
    replay.check_finite(replays, episodes)
    return choose_on_replayed(replays, episodes, tuning_objective(objective, domain), lag, max_delay,
                              long_subtasks, head)


def write_tuned(tuned: Tuned, params_file: str, domain: str | None, checkpoint: str, source: str) -> Path:
    """Write the choice as an ``ompn_node`` params file and into the checkpoint's detector.json (tuned on
    ``source``); returns the detector.json written."""
    objective = tuned.objective
    provenance = f"ompn_segment --tune on {source}, objective {objective}, online mode {tuned.best.mode}"
    write_node_config(params_file, domain or "", tuned.best, tuned.comparison,
                      f"{source}, objective {objective}, checkpoint {checkpoint}")
    measured = {**tuned.metrics, **tuned.figures}
    return replay.store_tuned(checkpoint, tuned.best, measured, provenance, tuned.model)


__all__ = ["Tuned", "tune_detector", "write_tuned"]
