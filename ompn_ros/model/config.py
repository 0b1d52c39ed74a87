"""OMPNConfig: the validated hyper-parameters of one OMPN policy, with a JSON round trip."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

from ompn_ros.data.cuts import check_tolerance
from ompn_ros.model.errors import ConfigError

CONFIG_VERSION = 1
"""Format version of :class:`OMPNConfig` (stored in every checkpoint's ``config.json``)."""

ActionType = Literal["discrete", "continuous"]
SketchMode = Literal["none", "sum"]
MemoryUpdate = Literal["paper", "code"]
Arch = Literal["ompn", "lstm"]
ActionNorm = Literal["none", "standard"]
ACTION_NORMS: tuple[ActionNorm, ...] = ("none", "standard")
ABLATIONS = ("no_bottom_up", "no_top_down", "no_bottom_up_recurrence")
"""The OMPN ablation flags (paper §4.4)."""


@dataclass
class OMPNConfig:
    """Hyper-parameters of the Ordered Memory Policy Network (paper §3, appendix A).

    Attributes:
        obs_dim: observation size (Craft 1075, Dial 39).
        action_type: ``'discrete'`` (categorical head) or ``'continuous'`` (Gaussian mean head).
        action_dim: discrete: number of env actions *excluding* done (Craft 5); continuous: the
            action vector size (Dial 9).
        n_slots: memory depth n (paper: 3).
        slot_size: slot size m = H (paper appendix: 128).
        sketch_mode: ``'none'`` (paper "NoSketch", task embedding e = 0) or ``'sum'`` (e = sum of
            learned subtask embeddings over the sketch; ids 0..sketch_vocab-1, -1 = padding).
        sketch_vocab: number of subtask ids (required > 0 with ``sketch_mode='sum'``).
        memory_update: ``'paper'`` = paper Eq. (2) M^t = M^{t-1}(1-cp) + C^t pi + M_hat(1-rcp);
            ``'code'`` = what the authors' code runs (docs/craft.md §3.5.4):
            M_i = rcp_i C_i + (1-rcp_i) M_hat_i.
        no_bottom_up: ablation "No Bottomup": skip the bottom-up pass (C_i := M^{t-1}_i).
        no_top_down: ablation "No Topdown": M_hat := 0.
        no_bottom_up_recurrence: ablation "No Bottomup Recurr": ComCell_i gets v = 0.
        action_variance: fixed variance of the Gaussian action distribution (continuous only).
        version: config format version, must equal :data:`CONFIG_VERSION`.
        arch: ``'ompn'`` (the ordered memory policy) or ``'lstm'`` (the behaviour-cloning baseline of
            ``lstm.py``: ``n_slots`` LSTM layers of width ``slot_size``; the OMPN ablation flags must
            be off).  Absent in configs written before it existed, which therefore read as ``'ompn'``.
        action_norm: continuous actions only: ``'none'`` (the head predicts raw actions) or
            ``'standard'`` (the head predicts ``(a - mean) / std`` per dimension, with the training
            split's statistics stored as the buffers ``action_mean`` / ``action_std``; the model
            outputs ``head * std + mean``, i.e. actions in the data's own units, and the Gaussian loss
            is taken on the standardised residual).  Absent in older configs: ``'none'``.
        still_tolerance: 0 (every observation is a step) or the tolerance below which an observation
            that changed no element since the last stepped one is not stepped, in training, the replay
            and ``ompn_node`` alike (:mod:`ompn_ros.data.cuts.still`, docs/design.md#still-observations).
            Always a number here: ``ompn_train``'s ``auto`` (its default) is resolved from the training
            episodes before the config is built.  Absent in older configs: 0.
    """

    obs_dim: int
    action_type: ActionType
    action_dim: int
    n_slots: int = 3
    slot_size: int = 128
    sketch_mode: SketchMode = "none"
    sketch_vocab: int = 0
    memory_update: MemoryUpdate = "paper"
    no_bottom_up: bool = False
    no_top_down: bool = False
    no_bottom_up_recurrence: bool = False
    action_variance: float = 0.6
    version: int = CONFIG_VERSION
    arch: Arch = "ompn"
    action_norm: ActionNorm = "none"
    still_tolerance: float = 0.0

    def __post_init__(self) -> None:
        for name in ("obs_dim", "action_dim", "n_slots", "slot_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ConfigError(f"OMPNConfig.{name} must be a positive int, got {value!r}")
        self._check_choice("action_type", ("discrete", "continuous"))
        self._check_sketch()
        self._check_choice("memory_update", ("paper", "code"))
        for name in ABLATIONS:
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"OMPNConfig.{name} must be a bool, got {getattr(self, name)!r}")
        if isinstance(self.action_variance, bool) or not isinstance(self.action_variance, int | float):
            raise ConfigError(f"OMPNConfig.action_variance must be a number, got {self.action_variance!r}")
        if not self.action_variance > 0:
            raise ConfigError(f"OMPNConfig.action_variance must be > 0, got {self.action_variance!r}")
        self.action_variance = float(self.action_variance)
        self._check_arch()
        self._check_action_norm()
        try:
            self.still_tolerance = check_tolerance(self.still_tolerance, "OMPNConfig.still_tolerance")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if self.version != CONFIG_VERSION:
            raise ConfigError(
                f"OMPNConfig.version {self.version!r} is not supported (this code reads version "
                f"{CONFIG_VERSION}); retrain or convert the checkpoint"
            )

    def _check_choice(self, name: str, allowed: tuple[str, str]) -> None:
        value = getattr(self, name)
        if value not in allowed:
            raise ConfigError(f"OMPNConfig.{name} must be {allowed[0]!r} or {allowed[1]!r}, got {value!r}")

    def _check_sketch(self) -> None:
        self._check_choice("sketch_mode", ("none", "sum"))
        if isinstance(self.sketch_vocab, bool) or not isinstance(self.sketch_vocab, int):
            raise ConfigError(f"OMPNConfig.sketch_vocab must be an int, got {self.sketch_vocab!r}")
        if self.sketch_mode == "sum" and self.sketch_vocab <= 0:
            raise ConfigError(
                "OMPNConfig.sketch_mode='sum' needs sketch_vocab > 0 (the number of subtask ids, "
                f"ids 0..sketch_vocab-1, -1 = padding), got sketch_vocab={self.sketch_vocab}"
            )
        if self.sketch_mode == "none" and self.sketch_vocab != 0:
            raise ConfigError(
                f"OMPNConfig.sketch_vocab={self.sketch_vocab} is only meaningful with sketch_mode='sum'; "
                "set sketch_vocab=0 or sketch_mode='sum'"
            )

    def _check_arch(self) -> None:
        self._check_choice("arch", ("ompn", "lstm"))
        if self.arch == "lstm":
            ablations = [name for name in ABLATIONS if getattr(self, name)]
            if ablations:
                raise ConfigError(
                    f"OMPNConfig.arch='lstm' has no ordered memory; unset the OMPN ablations {ablations}"
                )

    def _check_action_norm(self) -> None:
        if self.action_norm not in ACTION_NORMS:
            raise ConfigError(
                f"OMPNConfig.action_norm must be one of {ACTION_NORMS}, got {self.action_norm!r}"
            )
        if self.action_norm != "none" and self.action_type != "continuous":
            raise ConfigError(
                f"OMPNConfig.action_norm={self.action_norm!r} needs continuous actions (discrete actions "
                "are class indices)"
            )

    @property
    def n_actions_with_done(self) -> int:
        """Discrete: number of classes including the done class (index ``action_dim``)."""
        return self.action_dim + 1

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serializable dict (all fields, including ``version``)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OMPNConfig:
        """Build from :meth:`to_dict` output; unknown keys or a wrong version raise :class:`ConfigError`."""
        if not isinstance(data, dict):
            raise ConfigError(f"OMPNConfig.from_dict needs a dict, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown OMPNConfig keys {unknown}; known keys are {sorted(known)}")
        missing = sorted(k for k in ("obs_dim", "action_type", "action_dim") if k not in data)
        if missing:
            raise ConfigError(f"OMPNConfig is missing required keys {missing}")
        if "version" in data and data["version"] != CONFIG_VERSION:
            raise ConfigError(
                f"OMPNConfig version {data['version']!r} is not supported (expected {CONFIG_VERSION})"
            )
        return cls(**data)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> OMPNConfig:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"OMPNConfig JSON is not valid JSON: {exc}") from exc
        return cls.from_dict(data)
