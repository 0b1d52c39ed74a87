"""The online detector as an ``ompn_node`` ``--params-file`` (YAML) and back.

The file holds the node's ``detector_*`` parameters (:data:`~ompn_ros.detect.settings.DETECTOR_PARAMETERS`,
the same names :func:`~ompn_ros.detect.settings.node_parameters` fills from a checkpoint's
``detector.json``), so one shape of the settings runs from the file to the node: a params file
written by ``ompn_segment --tune`` is read by ``ompn_node --ros-args --params-file`` and by
``ompn_segment --detector-config`` alike.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from ompn_ros.detect.errors import TuneError
from ompn_ros.detect.online import DetectorConfig


def write_node_config(
    path: str | Path, domain: str, config: DetectorConfig, measured: dict[str, dict[str, float]], source: str
) -> Path:
    """Write an ``ompn_node`` ``--params-file`` with ``config``, the measurements as comments. O(1).
    Without a ``domain`` (a user's own data) the file sets none: ROS refuses a key without a value."""
    for_domain = f" for the {domain} domain" if domain else ""
    lines = [
        f"# ompn_node defaults{for_domain}, chosen by `ompn_segment --tune` on {source}.",
        "# Measured on the tuning episodes (online = these settings;",
        "# offline = whole-episode detectors with K = the true number of boundaries):",
    ]
    for name, m in measured.items():
        lines.append(f"#   {name}: " + ", ".join(f"{k}={v:.3f}" for k, v in m.items()))
    lines += [
        "/**/ompn_node:",
        "  ros__parameters:",
        *([f"    domain: {domain}"] if domain else []),
        f"    detector_high: {config.high}",
        f"    detector_hysteresis: {round(config.high - config.low_threshold, 4)}",
        f"    detector_min_segment_length: {config.min_segment_length}",
        f"    detector_mode: {config.mode}",
        f"    detector_force_first_step_low: {str(config.force_first_step_low).lower()}",
        f"    detector_lag: {config.lag}",
        f"    detector_offset: {config.offset}",
        "",
    ]
    out = Path(path)
    out.write_text("\n".join(lines), encoding="utf-8")
    return out


def load_detector_yaml(path: str | Path) -> DetectorConfig:
    """Detector settings from an ompn_node params file (``detector_*`` keys) or a plain mapping."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise TuneError(f"detector config {path}: {str(exc).splitlines()[0]}") from exc
    for _ in range(3):  # unwrap '/**' / node name / 'ros__parameters'
        if isinstance(data, dict) and len(data) == 1 and not any(str(k).startswith("detector") for k in data):
            data = next(iter(data.values()))
    if not isinstance(data, dict):
        raise TuneError(f"detector config {path}: expected a mapping with detector_* keys")
    params = {k[len("detector_") :]: v for k, v in data.items() if str(k).startswith("detector_")}
    if "hysteresis" in params:
        hysteresis = float(params.pop("hysteresis"))
        if hysteresis > 0:
            params["low"] = max(0.0, round(float(params.get("high", 0.5)) - hysteresis, 6))
    return DetectorConfig.from_dict(params)


__all__ = ["load_detector_yaml", "write_node_config"]
