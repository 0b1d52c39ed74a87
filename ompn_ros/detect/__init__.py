"""Subtask-boundary detectors over expansion distributions (offline; the online ones live in
``ompn_ros.detect.online``) and the scoring and tuning of the online detector (``ompn_ros.detect.tune``)."""

from ompn_ros.detect.errors import DetectorError, TuneError
from ompn_ros.detect.offline import (
    FALLBACK_THRESHOLD,
    AutoThreshold,
    auto_threshold,
    auto_threshold_boundaries,
    boundaries_from_threshold,
    constrained_top_k_boundaries,
    depth_scores,
    pi_avg,
    standardise,
    threshold_boundaries,
    top_k_boundaries,
)
from ompn_ros.detect.tune import (
    DEFAULT_OBJECTIVE,
    OBJECTIVES,
    choose_on_replays,
    compare_on_replays,
    default_grid,
    load_detector_yaml,
    score_online,
    write_node_config,
)

__all__ = [
    "DEFAULT_OBJECTIVE",
    "FALLBACK_THRESHOLD",
    "OBJECTIVES",
    "AutoThreshold",
    "DetectorError",
    "TuneError",
    "auto_threshold",
    "auto_threshold_boundaries",
    "boundaries_from_threshold",
    "choose_on_replays",
    "compare_on_replays",
    "constrained_top_k_boundaries",
    "default_grid",
    "depth_scores",
    "load_detector_yaml",
    "pi_avg",
    "score_online",
    "standardise",
    "threshold_boundaries",
    "top_k_boundaries",
    "write_node_config",
]
