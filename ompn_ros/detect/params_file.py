"""The online detector as an ``ompn_node`` ``--params-file`` (YAML) and back.

The file holds the node's ``detector_*`` parameters (:data:`~ompn_ros.detect.settings.DETECTOR_PARAMETERS`,
written by :func:`~ompn_ros.detect.settings.detector_parameters`, the way
:func:`~ompn_ros.detect.settings.node_parameters` fills them from a checkpoint's ``detector.json``), so
one shape of the settings runs from the file to the node: a params file
written by ``ompn_segment --tune`` is read by ``ompn_node --ros-args --params-file`` and by
``ompn_segment --detector-config`` alike.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ompn_ros.detect.errors import TuneError
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import HYSTERESIS, PARAMETER_PREFIX, detector_parameters

FILE_DIGITS = 4
"""Decimals of ``detector_hysteresis`` in a written file (the node's own way keeps 6)."""
READ_DIGITS = 6
"""Decimals of the ``low`` (``high - detector_hysteresis``) a read file gives (the node's is not rounded)."""


def write_node_config(
    path: str | Path, domain: str, config: DetectorConfig, measured: dict[str, dict[str, float]], source: str
) -> Path:
    """Write an ``ompn_node`` ``--params-file`` with ``config``, the measurements as comments. O(1).
    Without a ``domain`` (a user's own data) the file sets none: ROS refuses a key without a value."""
    for_domain = f" for the {domain} domain" if domain else ""
    parameters = detector_parameters(config, FILE_DIGITS)  # the node's names, in the node's types
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
        *(f"    {name}: {_scalar(value)}" for name, value in parameters.items()),
        "",
    ]
    out = Path(path)
    out.write_text("\n".join(lines), encoding="utf-8")
    return out


def load_detector_yaml(path: str | Path) -> DetectorConfig:
    """Detector settings from an ompn_node params file (``detector_*`` keys) or a plain mapping.

    Any of the names may be given, the others keep :class:`DetectorConfig`'s defaults; ``detector_low``
    is read as the field itself.  ``detector_hysteresis`` above 0 gives ``low = high - hysteresis``
    rounded to ``READ_DIGITS`` decimals (the tuned values back as written), 0 leaves ``low`` unset."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise TuneError(f"detector config {path}: {str(exc).splitlines()[0]}") from exc
    for _ in range(3):  # unwrap '/**' / node name / 'ros__parameters'
        if isinstance(data, dict) and len(data) == 1 and not any(str(k).startswith("detector") for k in data):
            data = next(iter(data.values()))
    if not isinstance(data, dict):
        raise TuneError(f"detector config {path}: expected a mapping with detector_* keys")
    params = {k[len(PARAMETER_PREFIX) :]: v for k, v in data.items()
              if str(k).startswith(PARAMETER_PREFIX) and k != HYSTERESIS}
    if HYSTERESIS in data:
        hysteresis = float(data[HYSTERESIS])
        if hysteresis > 0:
            high = float(params.get("high", DetectorConfig.high))  # the field's default
            params["low"] = max(0.0, round(high - hysteresis, READ_DIGITS))
    return DetectorConfig.from_dict(params)


def _scalar(value: Any) -> str:
    """A parameter value as YAML writes it (``true``/``false`` for a bool)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


__all__ = ["load_detector_yaml", "write_node_config"]
