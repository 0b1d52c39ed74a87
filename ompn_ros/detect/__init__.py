"""Subtask-boundary detectors over expansion distributions (offline; the online ones live in
``ompn_ros.detect.online``) and the scoring and tuning of the online detector (``ompn_ros.detect.tune``)."""

from typing import TYPE_CHECKING

from ompn_ros.lazy import lazy_names

if TYPE_CHECKING:  # the names below load on first use (PEP 562): importing a submodule stays light
    from ompn_ros.detect.defaults import DEFAULT_OBJECTIVE, OBJECTIVES
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
    from ompn_ros.detect.params_file import load_detector_yaml, write_node_config
    from ompn_ros.detect.tune import choose_on_replays, compare_on_replays, default_grid, score_online


_LAZY = {
    "DetectorError": "ompn_ros.detect.errors",
    "TuneError": "ompn_ros.detect.errors",
    "FALLBACK_THRESHOLD": "ompn_ros.detect.offline",
    "AutoThreshold": "ompn_ros.detect.offline",
    "auto_threshold": "ompn_ros.detect.offline",
    "auto_threshold_boundaries": "ompn_ros.detect.offline",
    "boundaries_from_threshold": "ompn_ros.detect.offline",
    "constrained_top_k_boundaries": "ompn_ros.detect.offline",
    "depth_scores": "ompn_ros.detect.offline",
    "pi_avg": "ompn_ros.detect.offline",
    "standardise": "ompn_ros.detect.offline",
    "threshold_boundaries": "ompn_ros.detect.offline",
    "top_k_boundaries": "ompn_ros.detect.offline",
    "DEFAULT_OBJECTIVE": "ompn_ros.detect.defaults",
    "OBJECTIVES": "ompn_ros.detect.defaults",
    "choose_on_replays": "ompn_ros.detect.tune",
    "compare_on_replays": "ompn_ros.detect.tune",
    "default_grid": "ompn_ros.detect.tune",
    "load_detector_yaml": "ompn_ros.detect.params_file",
    "score_online": "ompn_ros.detect.tune",
    "write_node_config": "ompn_ros.detect.params_file",
}

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


__getattr__ = lazy_names(__name__, globals(), _LAZY)
