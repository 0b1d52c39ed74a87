"""Detector settings that travel with a checkpoint: ``detector.json`` in its directory.

A checkpoint directory (or an ensemble directory, next to ``ensemble.json``) may hold
``detector.json``: the causal detector that ``ompn_node`` and ``ompn_segment`` run by default, the
node's ``done_threshold``, the offline whole-episode detector and its ``min_length``, where the
values came from (``source``) and what they measured.  Layout::

    {"format": "ompn_ros.detector", "format_version": 1,
     "online": {"high": 0.2, "low": null, "min_segment_length": 1, "mode": "falling_edge",
                "force_first_step_low": true},
     "done_threshold": 0.5,
     "offline": {"detector": "constrained_top_k", "min_length": 2},
     "duration_model": {"subtasks": 4, "hazard": [[...]], "f0": [...], "f1": [...], "episodes": 240},
     "source": "tuned_on_validation", "provenance": "...", "metrics": {"f1_tol1": 0.94}}

``duration_model`` (optional) is what the online mode 'hsmm' decodes with
(:mod:`ompn_ros.detect.duration`); an online detector of that mode needs it.  ``boundary_head``
(optional) describes the learned boundary head of the online mode 'head' (:mod:`ompn_ros.detect.head`):
its sizes, and its weights in ``boundary_head.safetensors`` beside ``detector.json``, whose header is
checked against those sizes before any weight is read.

One shape from file to node: :class:`DetectorSettings` is ``detector.json``
(:meth:`~DetectorSettings.to_dict`, :meth:`~DetectorSettings.from_dict`); its ``online`` part is the
:class:`~ompn_ros.detect.online.DetectorConfig` every detector is built from, held, not copied.  The
node's ``detector_*`` parameters are that config's fields under :func:`parameter_name` (``low`` given as
``detector_hysteresis``): :func:`detector_parameters` is the one way there, for the node
(:func:`node_parameters`) and an ``ompn_node --params-file`` (:mod:`ompn_ros.detect.params_file`);
:func:`detector_config` is the node's way back, ``load_detector_yaml`` a file's, each with its own
rounding of the hysteresis (docs/design.md#choosing-the-detector).  Which settings a checkpoint gets
is chosen in :mod:`ompn_ros.detect.choose`.

Precedence for every consumer: an explicit parameter (or ``--detector-config``) beats the
checkpoint's ``detector.json``, which beats the built-in defaults (``source = 'default'``).
The online detector is the causal form of the paper's Algorithm 1 (Lu et al., ICLR 2021, §3.3);
the offline detectors are Top-K, the automatic threshold (Algorithm 2) and the constrained Top-K.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, get_args

from ompn_ros.atomic import remove_stale_temps, temp_prefix, umask_mode
from ompn_ros.detect.defaults import DEFAULT_DONE_THRESHOLD, DEFAULT_MIN_LENGTH
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.errors import (
    BoundaryHeadError,
    DetectorConfigError,
    DetectorSettingsError,
    DurationModelError,
)
from ompn_ros.detect.head import BoundaryHead, load_head, write_head
from ompn_ros.detect.online import DURATION_MODES, HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.model.checkpoint_json import read_checkpoint_json

DETECTOR_FILE = "detector.json"
FORMAT = "ompn_ros.detector"
FORMAT_VERSION = 1
OfflineDetector = Literal["top_k", "auto_threshold", "constrained_top_k"]
SettingsSource = Literal["tuned_on_validation", "calibrated_label_free", "shipped", "default"]
OFFLINE_DETECTORS: tuple[OfflineDetector, ...] = get_args(OfflineDetector)
SOURCES: tuple[SettingsSource, ...] = get_args(SettingsSource)


def _where(origin: str, key: str) -> str:
    return f"{origin}: key '{key}'" if origin else f"detector settings key '{key}'"


@dataclass(frozen=True)
class DetectorSettings:
    """Online and offline detector choices of one checkpoint, validated on construction.

    Attributes:
        online: the causal detector (:class:`~ompn_ros.detect.online.DetectorConfig`).
        done_threshold: ``ompn_node`` publishes the done action when π_end exceeds it (in [0, 1]).
        offline_detector: whole-episode detector ('top_k', 'auto_threshold', 'constrained_top_k').
        min_length: minimum subtask length of the constrained Top-K, in steps (>= 1).
        source: 'tuned_on_validation' | 'calibrated_label_free' | 'shipped' | 'default'.
        provenance: one free-text line: how, on what and when the values were chosen.
        metrics: what the settings measured when chosen (name -> number).
        duration_model: the fitted model of the online mode 'hsmm' (None: that mode is unavailable).
        head: the trained boundary head of the online mode 'head' (None: that mode is unavailable).
    """

    online: DetectorConfig = field(default_factory=DetectorConfig)
    done_threshold: float = DEFAULT_DONE_THRESHOLD
    offline_detector: OfflineDetector = "top_k"
    min_length: int = DEFAULT_MIN_LENGTH
    source: SettingsSource = "default"
    provenance: str = "built-in defaults"
    metrics: dict[str, float] = field(default_factory=dict)
    duration_model: DurationModel | None = None
    head: BoundaryHead | None = None

    def __post_init__(self) -> None:
        self._check()

    def _check(self) -> None:
        """Raise :class:`DetectorSettingsError` naming the key at fault."""
        if not isinstance(self.online, DetectorConfig):
            raise DetectorSettingsError(f"{_where('', 'online')} must be a DetectorConfig")
        value = self.done_threshold
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
            raise DetectorSettingsError(f"{_where('', 'done_threshold')} must be in [0, 1], got {value!r}")
        if self.offline_detector not in OFFLINE_DETECTORS:
            raise DetectorSettingsError(
                f"{_where('', 'offline.detector')} must be one of {OFFLINE_DETECTORS}, "
                f"got {self.offline_detector!r}"
            )
        length = self.min_length
        if isinstance(length, bool) or not isinstance(length, int) or length < 1:
            raise DetectorSettingsError(
                f"{_where('', 'offline.min_length')} must be an int >= 1, got {length!r}"
            )
        if self.source not in SOURCES:
            raise DetectorSettingsError(
                f"{_where('', 'source')} must be one of {SOURCES}, got {self.source!r}"
            )
        if not isinstance(self.provenance, str) or "\n" in self.provenance:
            raise DetectorSettingsError(f"{_where('', 'provenance')} must be one line of text")
        if not isinstance(self.metrics, dict) or not all(
            isinstance(k, str) and isinstance(v, int | float) and not isinstance(v, bool)
            for k, v in self.metrics.items()
        ):
            raise DetectorSettingsError(f"{_where('', 'metrics')} must map names to numbers")
        if self.online.mode in DURATION_MODES and self.duration_model is None:
            raise DetectorSettingsError(
                f"{_where('', 'online.mode')} '{self.online.mode}' needs a 'duration_model', and there is "
                "none"
            )
        if self.online.mode in (HEAD_MODE, HEAD_DURATION_MODE) and self.head is None:
            raise DetectorSettingsError(
                f"{_where('', 'online.mode')} '{self.online.mode}' needs a 'boundary_head', and there is none"
            )
        if self.online.mode == HEAD_MODE and self.head is not None and self.online.lag > self.head.max_lag:
            raise DetectorSettingsError(
                f"{_where('', 'online.lag')} {self.online.lag} is beyond the boundary head's lags "
                f"(0 … {self.head.max_lag})"
            )

    def describe(self) -> str:
        """One log line: the online detector, its source and provenance."""
        c = self.online
        if c.mode in DURATION_MODES and self.duration_model is not None:
            model = self.duration_model
            what = (f"detector mode={c.mode} lag={c.lag} threshold={c.high} (K={model.subtasks}, "
                    f"fitted on {model.episodes} episodes)")
        elif c.mode == HEAD_MODE and self.head is not None:
            what = (f"detector mode={c.mode} lag={c.lag} threshold={c.high} gap={c.min_segment_length} "
                    f"peak={self.head.peak} (window {self.head.window}, trained on {self.head.episodes} "
                    "episodes)")
        else:
            what = (f"detector high={c.high} low={c.low_threshold} min_segment_length={c.min_segment_length} "
                    f"mode={c.mode}" + (f" offset={c.offset}" if c.offset else ""))
        return f"{what} done_threshold={self.done_threshold} (source: {self.source}; {self.provenance})"

    def to_dict(self) -> dict[str, Any]:
        data = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "online": self.online.to_dict(),
            "done_threshold": float(self.done_threshold),
            "offline": {"detector": self.offline_detector, "min_length": int(self.min_length)},
            "source": self.source,
            "provenance": self.provenance,
            "metrics": {k: _finite_or_none(v) for k, v in self.metrics.items()},
        }
        if self.duration_model is not None:
            data["duration_model"] = self.duration_model.to_dict()
        if self.head is not None:
            data["boundary_head"] = self.head.meta()
        return data

    @classmethod
    def from_dict(cls, data: Any, origin: str = "", directory: Path | None = None) -> DetectorSettings:
        """Parse the :meth:`to_dict` layout; errors name ``origin`` and the key.  A ``boundary_head``
        is read from ``directory`` (the checkpoint directory; required then)."""
        _check_layout(data, origin)
        online = _online_of(data, origin)
        offline = data.get("offline", {})
        if not isinstance(offline, dict) or set(offline) - {"detector", "min_length"}:
            raise DetectorSettingsError(f"{_where(origin, 'offline')} must be {{'detector', 'min_length'}}")
        metrics = data.get("metrics", {})
        if isinstance(metrics, dict):
            metrics = {k: math.nan if v is None else v for k, v in metrics.items()}
        model, head = _duration_model_of(data, origin), _head_of(data, origin, directory)
        try:
            return cls(
                online=online,
                done_threshold=data.get("done_threshold", DEFAULT_DONE_THRESHOLD),
                offline_detector=offline.get("detector", "top_k"),
                min_length=offline.get("min_length", DEFAULT_MIN_LENGTH),
                source=data.get("source", "default"),
                provenance=data.get("provenance", ""),
                metrics=metrics,
                duration_model=model,
                head=head,
            )
        except DetectorSettingsError as exc:
            raise DetectorSettingsError(f"{origin}: {exc}" if origin else str(exc)) from None


KNOWN_KEYS = frozenset({
    "format", "format_version", "online", "done_threshold", "offline", "source", "provenance", "metrics",
    "duration_model", "boundary_head",
})
"""The top-level keys of ``detector.json``."""


def _check_layout(data: Any, origin: str) -> None:
    """Raise :class:`DetectorSettingsError` unless ``data`` is an object of this format and version
    with known keys only."""
    if not isinstance(data, dict):
        raise DetectorSettingsError(f"{origin or 'detector settings'}: expected a JSON object")
    if data.get("format", FORMAT) != FORMAT:
        raise DetectorSettingsError(f"{_where(origin, 'format')} must be '{FORMAT}', got {data['format']!r}")
    version = data.get("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise DetectorSettingsError(
            f"{_where(origin, 'format_version')} {version!r} is not supported (this version reads "
            f"{FORMAT_VERSION})"
        )
    unknown = sorted(set(data) - KNOWN_KEYS)
    if unknown:
        raise DetectorSettingsError(
            f"{_where(origin, unknown[0])} is unknown; known keys: {sorted(KNOWN_KEYS)}"
        )


def _online_of(data: dict[str, Any], origin: str) -> DetectorConfig:
    try:
        return DetectorConfig.from_dict(dict(data.get("online", {})))
    except (DetectorConfigError, TypeError, ValueError) as exc:
        raise DetectorSettingsError(f"{_where(origin, 'online')}: {exc}") from exc


def _duration_model_of(data: dict[str, Any], origin: str) -> DurationModel | None:
    if data.get("duration_model") is None:
        return None
    try:
        return DurationModel.from_dict(data["duration_model"])
    except DurationModelError as exc:
        raise DetectorSettingsError(f"{_where(origin, 'duration_model')}: {exc}") from exc


def _head_of(data: dict[str, Any], origin: str, directory: Path | None) -> BoundaryHead | None:
    if data.get("boundary_head") is None:
        return None
    if directory is None:
        raise DetectorSettingsError(f"{_where(origin, 'boundary_head')}: its weights file is read "
                                    "from the checkpoint directory, and none was given")
    try:
        return load_head(directory, data["boundary_head"], origin or "detector settings")
    except BoundaryHeadError as exc:
        raise DetectorSettingsError(f"{_where(origin, 'boundary_head')}: {exc}") from exc


PARAMETER_PREFIX = "detector_"
"""A :class:`DetectorConfig` field ``x`` is the node parameter ``detector_x`` (:func:`parameter_name`)."""
HYSTERESIS = "detector_hysteresis"
"""The one ``detector_*`` parameter that is not a :class:`DetectorConfig` field's own name: it gives the
field ``low`` as ``high - low`` (the node's hysteresis, 0: ``low = high``)."""
_DEFAULT = DetectorConfig()


def parameter_name(field_name: str) -> str:
    """The ``ompn_node`` parameter of a :class:`DetectorConfig` field (``low``: :data:`HYSTERESIS`)."""
    return HYSTERESIS if field_name == "low" else PARAMETER_PREFIX + field_name


DETECTOR_PARAMETERS = tuple(parameter_name(spec.name) for spec in fields(DetectorConfig))
"""The ``ompn_node`` parameters of the online detector (:func:`detector_config`), one per field of
:class:`DetectorConfig` in its order; they apply live."""
NODE_PARAMETERS = (*DETECTOR_PARAMETERS, "done_threshold")
"""The ``ompn_node`` parameters that :func:`node_parameters` fills from the settings."""


def detector_parameters(config: DetectorConfig, digits: int = 6) -> dict[str, Any]:
    """``config`` as ``detector_*`` parameter values (``DETECTOR_PARAMETERS``, each of the type of its
    field's default), ``detector_hysteresis`` rounded to ``digits`` decimals: the one way from the
    detector to its parameters, for the node (6) and a params file (4, :mod:`ompn_ros.detect.params_file`)."""
    values: dict[str, Any] = {}
    for spec in fields(DetectorConfig):
        if spec.name == "low":
            values[HYSTERESIS] = round(float(config.high) - config.low_threshold, digits)
        else:
            values[parameter_name(spec.name)] = _of_field_kind(spec.name, getattr(config, spec.name))
    return values


def _of_field_kind(name: str, value: Any) -> Any:
    """``value`` as the type of field ``name``'s default (a ROS parameter has one type)."""
    return type(getattr(_DEFAULT, name))(value)


def node_parameters(settings: DetectorSettings) -> dict[str, Any]:
    """``ompn_node`` parameter values (``NODE_PARAMETERS``) equal to ``settings``.

    A node that declares these parameters with these values as defaults gets the precedence rule
    for free: a ``-p`` or ``--params-file`` value overrides the checkpoint's.  The way back is
    :func:`detector_config`.
    """
    return {**detector_parameters(settings.online), "done_threshold": float(settings.done_threshold)}


def detector_config(values: Mapping[str, Any]) -> DetectorConfig:
    """The detector of the ``detector_*`` parameter values, every one given (``low = high - hysteresis``).

    Raises :class:`DetectorConfigError` when ``detector_hysteresis`` exceeds ``detector_high`` (the run
    would end only below a score of 0, so it would never end)."""
    high, hysteresis = float(values[parameter_name("high")]), float(values[HYSTERESIS])
    if hysteresis > high + 1e-9:
        raise DetectorConfigError(
            f"detector_hysteresis={hysteresis} exceeds detector_high={high}: a run would end only below a "
            "score of 0; set detector_hysteresis <= detector_high"
        )
    given = {spec.name: _of_field_kind(spec.name, values[parameter_name(spec.name)])
             for spec in fields(DetectorConfig) if spec.name != "low"}
    return DetectorConfig(**given, low=max(0.0, high - hysteresis))


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def detector_file(checkpoint_dir: str | Path) -> Path:
    """``checkpoint_dir/detector.json`` (a checkpoint or an ensemble directory)."""
    return Path(checkpoint_dir) / DETECTOR_FILE


def save_detector_settings(checkpoint_dir: str | Path, settings: DetectorSettings) -> Path:
    """Write ``detector.json`` into ``checkpoint_dir`` atomically (temporary sibling + ``os.replace``),
    after the boundary head's weights when the settings carry one."""
    target = detector_file(checkpoint_dir)
    if not target.parent.is_dir():
        raise DetectorSettingsError(
            f"{target.parent}: not a directory (no checkpoint to add {DETECTOR_FILE} to)"
        )
    if settings.head is not None:
        write_head(target.parent, settings.head)
    text = json.dumps(settings.to_dict(), indent=1, allow_nan=False) + "\n"
    remove_stale_temps(target.parent, DETECTOR_FILE)
    handle = tempfile.NamedTemporaryFile(
        "w", encoding="utf-8", dir=target.parent, prefix=temp_prefix(DETECTOR_FILE), delete=False
    )
    try:
        with handle:
            os.fchmod(handle.fileno(), umask_mode())  # a published file follows the umask, not 0600
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(handle.name, target)
    except BaseException:
        Path(handle.name).unlink(missing_ok=True)
        raise
    return target


def load_detector_settings(checkpoint_dir: str | Path) -> DetectorSettings:
    """The settings stored with a checkpoint, or the defaults when it has none.

    A missing file is not an error (a checkpoint made without ``ompn_train`` has none): the defaults
    come back with ``source='default'`` and a warning as their ``provenance``.  An unreadable or
    invalid file is a :class:`DetectorSettingsError` naming the file and the key.
    """
    path = detector_file(checkpoint_dir)
    if not path.exists() and not path.is_symlink():  # a FIFO or a device there is refused when read
        warning = (
            f"WARNING: {path} not found, built-in defaults (high=0.5) may publish no boundaries for "
            "this model; calibrate with ompn_train or ompn_segment --tune --write-config"
        )
        return DetectorSettings(source="default", provenance=warning)
    data = read_checkpoint_json(path, DetectorSettingsError)
    return DetectorSettings.from_dict(data, origin=str(path), directory=path.parent)


def resolve_detector(
    checkpoint_dir: str | Path, explicit: DetectorConfig | None = None, explicit_origin: str = ""
) -> tuple[DetectorSettings, str]:
    """The settings a consumer runs with, and the log line saying which they are and where they came from.

    Precedence: ``explicit`` (a parameter or ``--detector-config``; ``explicit_origin`` names it) >
    ``checkpoint_dir/detector.json`` > built-in defaults.  With only the online detector given
    explicitly, the stored ``done_threshold`` and offline choices are kept.
    """
    stored = load_detector_settings(checkpoint_dir)
    if explicit is None:
        where = f" from {detector_file(checkpoint_dir)}" if stored.source != "default" else ""
        return stored, f"using {stored.describe()}{where}"
    settings = DetectorSettings(
        online=explicit,
        done_threshold=stored.done_threshold,
        offline_detector=stored.offline_detector,
        min_length=stored.min_length,
        source=stored.source,
        provenance=f"online detector from {explicit_origin or 'an explicit parameter'}, "
        f"overriding the checkpoint's ({stored.source})",
        metrics={},
        duration_model=stored.duration_model,
        head=stored.head,
    )
    return settings, f"using {settings.describe()}"


__all__ = [
    "DETECTOR_FILE",
    "DETECTOR_PARAMETERS",
    "HYSTERESIS",
    "NODE_PARAMETERS",
    "OFFLINE_DETECTORS",
    "PARAMETER_PREFIX",
    "SOURCES",
    "DetectorSettings",
    "OfflineDetector",
    "SettingsSource",
    "detector_config",
    "detector_file",
    "detector_parameters",
    "load_detector_settings",
    "node_parameters",
    "parameter_name",
    "resolve_detector",
    "save_detector_settings",
]
