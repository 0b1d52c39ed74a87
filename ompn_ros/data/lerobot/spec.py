"""Which features of a LeRobot dataset are the observation, the action and the labels.

The YAML form (``config/dataset_example.yaml``) holds the keys under an optional ``dataset:`` key::

    observation: [observation.state]   # one feature or several, concatenated in this order
    action: action                     # a float vector (continuous) or one integer (discrete)
    labels: null                       # an integer feature per frame, or null (no labels)
    label_kind: id                     # id: a new subtask wherever the value changes; ordinal: 0, 1, ...

Video and image features are read only when named, and cannot be named (the model reads vectors):
the reader says in one line which it left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import yaml

from ompn_ros.data.errors import DatasetSpecError

LabelKind = Literal["id", "ordinal"]
KEYS = ("observation", "action", "labels", "label_kind")


@dataclass(frozen=True)
class DatasetSpec:
    """What to read from a dataset: feature names (see the module doc)."""

    observation: tuple[str, ...] = ("observation.state",)
    action: str = "action"
    labels: str | None = None
    label_kind: LabelKind = "id"

    def __post_init__(self) -> None:
        if not self.observation or not all(isinstance(n, str) and n for n in self.observation):
            raise DatasetSpecError(f"dataset spec: 'observation' must name one feature or more, got "
                                   f"{list(self.observation)!r}")
        if not isinstance(self.action, str) or not self.action:
            raise DatasetSpecError(f"dataset spec: 'action' must name a feature, got {self.action!r}")
        if self.labels is not None and (not isinstance(self.labels, str) or not self.labels):
            raise DatasetSpecError(f"dataset spec: 'labels' must name a feature or be null, got "
                                   f"{self.labels!r}")
        if self.label_kind not in get_args(LabelKind):
            raise DatasetSpecError(f"dataset spec: 'label_kind' must be one of {get_args(LabelKind)}, "
                                   f"got {self.label_kind!r}")
        named = [*self.observation, self.action, *([self.labels] if self.labels else [])]
        if len(set(named)) != len(named):
            raise DatasetSpecError(f"dataset spec: a feature is named twice in {named}")

    @property
    def features(self) -> tuple[str, ...]:
        """Every feature the spec names, observation first."""
        return (*self.observation, self.action, *((self.labels,) if self.labels else ()))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DatasetSpec:
        """A spec from a mapping with :data:`KEYS` (``observation`` may be one name or a list)."""
        unknown = sorted(set(data) - set(KEYS))
        if unknown:
            raise DatasetSpecError(f"dataset spec: unknown key(s) {unknown}; the keys are {list(KEYS)}")
        observation = data.get("observation", cls.observation)
        if isinstance(observation, str):
            observation = [observation]
        if not isinstance(observation, (list, tuple)):
            raise DatasetSpecError(f"dataset spec: 'observation' must be a name or a list, got "
                                   f"{observation!r}")
        return cls(observation=tuple(observation), action=data.get("action", cls.action),
                   labels=data.get("labels"), label_kind=data.get("label_kind", "id"))

    @classmethod
    def from_yaml(cls, path: str | Path) -> DatasetSpec:
        """A spec from a YAML file (keys at the top or under ``dataset:``)."""
        try:
            data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
        except (UnicodeDecodeError, yaml.YAMLError) as exc:
            raise DatasetSpecError(f"dataset spec {path} is not valid YAML: {exc}") from exc
        if isinstance(data, dict) and isinstance(data.get("dataset"), dict):
            data = data["dataset"]
        if not isinstance(data, dict):
            raise DatasetSpecError(f"dataset spec {path} must hold a mapping with keys {list(KEYS)}")
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        return {"observation": list(self.observation), "action": self.action, "labels": self.labels,
                "label_kind": self.label_kind}


__all__ = ["KEYS", "DatasetSpec", "LabelKind"]
