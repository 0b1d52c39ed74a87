"""A run scored as the product runs it: every episode replayed through the node's segmenter (the done
step included, as live) with the detector ``ompn_train`` bundled, and the domain's primary offline
detector read from the same replays (docs/experiments.md §55).

This is the one scoring that holds for a model with ``model.still_tolerance``: the replay steps only the
observations that moved and maps every boundary back to the stream's rows (:mod:`ompn_ros.data.cuts.still`),
where the teacher-forced evaluation of the other studies would step every row.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ompn_ros.app.replay import replay_all
from ompn_ros.data.episode import Episode
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.detect.tune import compare_on_replays
from ompn_ros.model.load import stepper_from_checkpoint

OFFLINE = {"craft": "offline_topk", "dial": "offline_auto"}
"""The domain's primary offline detector (Top-K for Craft, the automatic threshold for Dial)."""


def replayed_figures(checkpoint: Path, domain: str, episodes: Sequence[Episode]) -> dict[str, Any]:
    """Offline and online alignment and F1@1 (%), the online mean delay (steps) and share of inner
    boundaries published at the episode end, of ``checkpoint`` on ``episodes`` (labelled)."""
    settings = load_detector_settings(checkpoint)
    stepper = stepper_from_checkpoint(checkpoint)
    replays = replay_all(stepper, list(episodes), settings.online, settings.duration_model, settings.head)
    got = compare_on_replays(replays, list(episodes), {"online": settings.online},
                             duration_model=settings.duration_model, head=settings.head)
    offline, online = got[OFFLINE[domain]], got["online"]
    return {
        "offline_align": round(100 * offline["align"], 1),
        "offline_f1_1": round(100 * offline["f1_tol1"], 1),
        "online_align": round(100 * online["align"], 1),
        "online_f1_1": round(100 * online["f1_tol1"], 1),
        "delay_mean": round(float(online["delay_mean"]), 2),
        "at_end_share": round(100 * online["at_end_share"], 1),
        "online_mode": settings.online.mode,
        "still_tolerance": float(getattr(stepper.config, "still_tolerance", 0.0)),
    }
