"""Subtask-boundary detectors over expansion distributions (offline; the online ones live in
``ompn_ros.detect.online``)."""

from ompn_ros.detect.offline import (
    FALLBACK_THRESHOLD,
    AutoThreshold,
    DetectorError,
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

__all__ = [
    "FALLBACK_THRESHOLD",
    "AutoThreshold",
    "DetectorError",
    "auto_threshold",
    "auto_threshold_boundaries",
    "boundaries_from_threshold",
    "constrained_top_k_boundaries",
    "depth_scores",
    "pi_avg",
    "standardise",
    "threshold_boundaries",
    "top_k_boundaries",
]
