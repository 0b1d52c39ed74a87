"""ObservationSpec: which fields of which topics make up one observation vector (validated).

The same block configures the bag reader (reader-spec YAML) and ``ompn_node`` (params file)::

    observation:
      step_topic: /arm1/joint_states        # its messages are the steps (the observation clock)
      tolerance_s: 0.05                     # a partner may be this much older than the step
      wait_s: 0.1                           # how long a step may wait for a header-stamped partner
      stamp: header                         # header | receive (see ompn_ros.data.obs.assembler)
      fields:                               # concatenated in this order
        - {topic: /arm1/joint_states, type: sensor_msgs/msg/JointState, field: position,
           names: [j1, j2, j3]}             # joint subset and order
        - {topic: /arm1/gripper, type: std_msgs/msg/Float32MultiArray, field: data, size: 2}
        - {topic: /arm1/wrench, type: geometry_msgs/msg/WrenchStamped, field: wrench}

Type names are the ROS 2 spellings (``pkg/msg/Type``; ``pkg/Type`` and, for the types of
:data:`FIELDS`, the bare ``Type`` are accepted too).  Any other type is read through a field path
(``field: gripper.width``, ``twist.linear``, ``points[-1].positions``; docs/specs.md), its definition
coming from the bag, a ``.msg`` folder or its installed package.  Every error is one
:class:`ObservationSpecError` line naming the entry at fault, e.g. ``fields[2]: field 'positon' of
topic '/arm1/joint_states': sensor_msgs/msg/JointState: field path 'positon': ... has no field``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Final, Literal

from ompn_ros.data.errors import ObservationSpecError
from ompn_ros.data.messages.fieldpath import FieldPathError, Target, describe, parse_path
from ompn_ros.data.messages.types import full_name, known
from ompn_ros.layout import (
    FLOAT32,
    FLOAT32_ARRAY,
    FLOAT64,
    FLOAT64_ARRAY,
    JOINT_FIELDS,
    JOINT_STATE,
    POSE_STAMPED,
    WRENCH_STAMPED,
)

StampSource = Literal["header", "receive"]

FIELDS: Final[dict[str, tuple[str, ...]]] = {
    JOINT_STATE: JOINT_FIELDS,
    FLOAT32_ARRAY: ("data",),
    FLOAT64_ARRAY: ("data",),
    FLOAT32: ("data",),
    FLOAT64: ("data",),
    WRENCH_STAMPED: ("force", "torque", "wrench"),
    POSE_STAMPED: ("position", "orientation", "pose"),
}
"""Supported message types and the fields an observation may take from each."""

HAS_HEADER: Final = frozenset({JOINT_STATE, WRENCH_STAMPED, POSE_STAMPED})
VARIABLE_SIZE: Final = frozenset({JOINT_STATE, FLOAT32_ARRAY, FLOAT64_ARRAY})
"""Types whose field size is not fixed by the type (declared by ``names``/``size`` or the first message)."""

FIXED_LABELS: Final[dict[tuple[str, str], tuple[str, ...]]] = {
    (FLOAT32, "data"): ("data",),
    (FLOAT64, "data"): ("data",),
    (WRENCH_STAMPED, "force"): ("x", "y", "z"),
    (WRENCH_STAMPED, "torque"): ("x", "y", "z"),
    (WRENCH_STAMPED, "wrench"): ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z"),
    (POSE_STAMPED, "position"): ("x", "y", "z"),
    (POSE_STAMPED, "orientation"): ("x", "y", "z", "w"),
    (POSE_STAMPED, "pose"): ("position.x", "position.y", "position.z",
                             "orientation.x", "orientation.y", "orientation.z", "orientation.w"),
}
"""Element labels of the fixed-size fields (their size is the number of labels)."""


def canonical_type(name: str) -> str | None:
    """``pkg/msg/Type`` of a type given as ``pkg/msg/Type`` or ``pkg/Type`` (any type), or as the bare
    ``Type`` of a fast-parsed one (:data:`FIELDS`); ``None`` for a bare name of another type."""
    base = name.rsplit("/", 1)[-1]
    for full in FIELDS:
        if name == full or (full.endswith("/" + base) and name in (base, full.replace("/msg/", "/"))):
            return full
    parts = name.strip("/").split("/")
    if len(parts) in (2, 3) and all(parts) and (len(parts) == 2 or parts[1] == "msg"):
        return full_name(name)
    return None


@dataclass(frozen=True)
class FieldSpec:
    """One part of the observation: ``field`` of the messages of ``topic`` (of type ``type``).

    Attributes:
        topic: topic name; relative names follow the namespace (:meth:`ObservationSpec.with_namespace`).
        type: message type (see :data:`FIELDS`), normalised to ``pkg/msg/Type``.
        field: which part of the message (``JointState``: position/velocity/effort; MultiArray and
            Float32/Float64: data; WrenchStamped: force/torque/wrench; PoseStamped:
            position/orientation/pose).
        names: ``JointState``: the joints taken, in this order (a subset of the message's joints);
            MultiArray: labels of the elements (fixes the size).  ``None``: JointState takes the joints
            of the first message in their order, MultiArray labels its elements ``0..n-1``.
        size: declared number of elements (MultiArray only; checked on every message).
    """

    topic: str
    type: str
    field: str
    names: tuple[str, ...] | None = None
    size: int | None = None

    def __post_init__(self) -> None:
        at = f"field {self.field!r} of topic {self.topic!r}"
        if not isinstance(self.topic, str) or not self.topic.strip("/"):
            raise ObservationSpecError(f"{at}: the topic must be a non-empty name")
        full = canonical_type(self.type) if isinstance(self.type, str) else None
        if full is None:
            raise ObservationSpecError(f"{at}: message type {self.type!r} needs its package (pkg/msg/Type); "
                                       f"the bare names known are those of {sorted(FIELDS)}")
        object.__setattr__(self, "type", full)
        if self.generic:
            self._check_path(at, full)
        self._check_names_and_size(at, full)

    @property
    def generic(self) -> bool:
        """Whether the field is a field path read through the type's definition (else a fast parser)."""
        return self.field not in FIELDS.get(self.type, ())

    def _check_path(self, at: str, full: str) -> None:
        """The path's syntax, and its target when the type is already known (a bag's own type is
        checked when its definition is registered, :meth:`target`)."""
        try:
            parse_path(self.field)
            if known(full):
                target = describe(full, self.field)
                if target.kind == "string":
                    raise FieldPathError(f"{full}: field path '{self.field}' is a string, not a number")
        except FieldPathError as err:
            raise ObservationSpecError(f"{at}: {err}") from None

    def target(self) -> Target | None:
        """What a field path leads to (``None`` for a fast field or a type not registered yet)."""
        if not self.generic or not known(self.type):
            return None
        return describe(self.type, self.field)

    def _check_names_and_size(self, at: str, full: str) -> None:
        if self.names is not None:
            if full not in VARIABLE_SIZE and not self.generic:
                raise ObservationSpecError(f"{at}: names are not allowed for {full} (its labels are fixed)")
            names = tuple(self.names) if isinstance(self.names, (list, tuple)) else None
            if not names or not all(isinstance(n, str) and n for n in names):
                raise ObservationSpecError(f"{at}: names must be a non-empty list of names, "
                                           f"got {self.names!r}")
            if len(set(names)) != len(names):
                raise ObservationSpecError(f"{at}: names has duplicates: {list(names)}")
            object.__setattr__(self, "names", names)
        if self.size is not None:
            if full not in (FLOAT32_ARRAY, FLOAT64_ARRAY) and not self.generic:
                has = "names" if full == JOINT_STATE else "a fixed size"
                raise ObservationSpecError(f"{at}: only MultiArray fields declare a size ({full} has {has})")
            if isinstance(self.size, bool) or not isinstance(self.size, int) or self.size <= 0:
                raise ObservationSpecError(f"{at}: size must be a positive int, got {self.size!r}")
            if self.names is not None and len(self.names) != self.size:
                raise ObservationSpecError(f"{at}: {len(self.names)} names but size {self.size}")

    @property
    def declared_size(self) -> int | None:
        """Number of elements known from the spec alone, ``None`` when the first message decides."""
        fixed = FIXED_LABELS.get((self.type, self.field)) or self._path_labels()
        if fixed is not None and self.names is None:
            return len(fixed)
        if self.names is not None:
            return len(self.names)
        return self.size

    def _path_labels(self) -> tuple[str, ...] | None:
        """Labels a field path's type fixes (a scalar is labelled by its last field name)."""
        target = self.target()
        if target is None or target.labels is None:
            return None
        if target.labels == ("",):
            return (self.field.rsplit(".", 1)[-1].split("[", 1)[0],)
        return target.labels

    def labels(self, size: int, joint_names: Sequence[str] | None = None) -> tuple[str, ...]:
        """Element labels for a field of ``size`` elements (``joint_names``: a JointState's own order)."""
        if self.names is not None:
            return self.names
        fixed = FIXED_LABELS.get((self.type, self.field)) or self._path_labels()
        if fixed is not None:
            return fixed
        if joint_names is not None:
            return tuple(joint_names)
        return tuple(str(i) for i in range(size))

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (YAML/JSON friendly), only the keys that differ from the defaults."""
        out: dict[str, Any] = {"topic": self.topic, "type": self.type, "field": self.field}
        if self.names is not None:
            out["names"] = list(self.names)
        if self.size is not None:
            out["size"] = self.size
        return out


@dataclass(frozen=True)
class ObservationSpec:
    """The observation: ``fields`` concatenated in order, one vector per message of ``step_topic``.

    Attributes:
        step_topic: the step clock; every message on it is one step (one observation or one drop).
        fields: the parts of the observation, in order (fields of the step topic included).
        tolerance_s: how much older (seconds) than the step a partner message may be.
        wait_s: how long (seconds, on the caller's receive clock) a step is held while a partner
            topic stamped by its headers has not yet offered a message stamped at or after the step
            (:meth:`ObservationAssembler.hold`); ``0`` decides every step on arrival.  Partners stamped
            at reception are never waited for: their later messages are stamped later anyway.
        stamp: ``'header'``: a message's stamp is its ``header.stamp`` when its type has one and it is
            not zero, else the receive/record time; ``'receive'``: always the receive/record time
            (use it when the topics' header stamps are not on one clock).
    """

    step_topic: str
    fields: tuple[FieldSpec, ...]
    tolerance_s: float = 0.05
    wait_s: float = 0.1
    stamp: StampSource = "header"

    def __post_init__(self) -> None:
        if not isinstance(self.step_topic, str) or not self.step_topic.strip("/"):
            raise ObservationSpecError(f"step_topic must be a non-empty topic name, got {self.step_topic!r}")
        object.__setattr__(self, "fields", tuple(self.fields))
        if not self.fields:
            raise ObservationSpecError("fields must list at least one field")
        tol = self.tolerance_s
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 <= tol < float("inf"):
            raise ObservationSpecError(f"tolerance_s must be a finite number >= 0, got {tol!r}")
        wait = self.wait_s
        if isinstance(wait, bool) or not isinstance(wait, (int, float)) or not 0 <= wait < float("inf"):
            raise ObservationSpecError(f"wait_s must be a finite number >= 0, got {wait!r}")
        if self.stamp not in ("header", "receive"):
            raise ObservationSpecError(f"stamp must be 'header' or 'receive', got {self.stamp!r}")
        types: dict[str, tuple[str, str]] = {}
        seen: dict[tuple[str, str, tuple[str, ...] | None], str] = {}
        for i, f in enumerate(self.fields):
            at = f"fields[{i}]"
            if not isinstance(f, FieldSpec):
                raise ObservationSpecError(f"{at} must be a FieldSpec, got {type(f).__name__}")
            prev = types.setdefault(f.topic, (f.type, at))
            if prev[0] != f.type:
                raise ObservationSpecError(f"{at}.type: topic '{f.topic}' is {prev[0]} in {prev[1]}, "
                                           f"not {f.type}")
            key = (f.topic, f.field, f.names)  # the same field may appear again with other joints
            if key in seen:
                raise ObservationSpecError(f"{at}: field '{f.field}' of '{f.topic}' is already {seen[key]}")
            seen[key] = at
        if self.step_topic not in types:
            raise ObservationSpecError(f"step_topic '{self.step_topic}' gives no field; the step topic must "
                                       f"be the topic of at least one field (topics: {sorted(types)})")

    # --- views -------------------------------------------------------------------------------------
    @property
    def topics(self) -> dict[str, str]:
        """Every topic of the spec and its type, the step topic first."""
        out = {self.step_topic: self.type_of(self.step_topic)}
        for f in self.fields:
            out.setdefault(f.topic, f.type)
        return out

    @property
    def partner_topics(self) -> tuple[str, ...]:
        """The topics other than the step topic, in first-field order."""
        return tuple(t for t in self.topics if t != self.step_topic)

    def type_of(self, topic: str) -> str:
        """Message type of ``topic`` (KeyError when the spec does not use it)."""
        for f in self.fields:
            if f.topic == topic:
                return f.type
        raise KeyError(topic)

    def declared_dim(self) -> int | None:
        """Observation size known from the spec alone, ``None`` when a first message decides."""
        sizes = [f.declared_size for f in self.fields]
        return None if any(s is None for s in sizes) else sum(s for s in sizes if s is not None)

    def check_types(self, types: Mapping[str, str]) -> list[str]:
        """One line per spec topic whose type in ``types`` (topic -> type name) differs from the spec."""
        problems = []
        for topic, want in self.topics.items():
            got = types.get(topic)
            if got is not None and canonical_type(got) != want:
                problems.append(f"topic '{topic}' has type {got}, the observation spec expects {want}")
        return problems

    def with_namespace(self, namespace: str) -> ObservationSpec:
        """The same spec with relative topic names resolved in ``namespace`` (absolute names kept)."""
        new_fields = tuple(replace(f, topic=resolve_name(f.topic, namespace)) for f in self.fields)
        return replace(self, step_topic=resolve_name(self.step_topic, namespace), fields=new_fields)

    # --- (de)serialisation ------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ObservationSpec:
        """Build from the YAML form (an outer ``observation:`` key is accepted)."""
        if isinstance(data, Mapping) and set(data) == {"observation"}:
            data = data["observation"]
        if not isinstance(data, Mapping):
            raise ObservationSpecError(f"observation spec must be a mapping, got {type(data).__name__}")
        _reject_unknown("observation", data, {f.name for f in fields(cls)})
        for key in ("step_topic", "fields"):
            if key not in data:
                raise ObservationSpecError(f"observation.{key} is missing")
        raw_fields = data["fields"]
        if not isinstance(raw_fields, Sequence) or isinstance(raw_fields, str):
            raise ObservationSpecError("observation.fields must be a list of field mappings")
        parsed = tuple(_field_from_dict(i, item) for i, item in enumerate(raw_fields))
        kwargs = {k: v for k, v in data.items() if k != "fields"}
        return cls(fields=parsed, **kwargs)

    @classmethod
    def single_topic(
        cls, topic: str, size: int | None = None, type_name: str = FLOAT32_ARRAY
    ) -> ObservationSpec:
        """The one-topic observation (e.g. our sims' ``observation`` Float32MultiArray)."""
        return cls(step_topic=topic, fields=(FieldSpec(topic, type_name, "data", size=size),))

    @classmethod
    def from_yaml(cls, path: str | Path) -> ObservationSpec:
        """Load from a YAML file: the spec mapping itself, or a file with an ``observation:`` block
        among other keys (a params file), or a reader spec with an ``assemble:`` block."""
        import yaml

        try:
            with open(path, encoding="utf-8") as fh:
                data = yaml.safe_load(fh)
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
            raise ObservationSpecError(f"cannot read observation spec '{path}': {err}") from err
        try:
            return cls.from_dict(_observation_block(data))
        except ObservationSpecError as err:
            raise ObservationSpecError(f"{path}: {err}") from err

    @classmethod
    def from_param(cls, value: str) -> ObservationSpec:
        """From a string parameter: inline YAML/JSON (a mapping, e.g. ``{step_topic: ..., fields: [...]}``)
        or the path of a YAML file (see :meth:`from_yaml`)."""
        import yaml

        text = value.strip()
        if not text:
            raise ObservationSpecError("observation spec parameter is empty")
        if not text.startswith("{") and "\n" not in text:
            return cls.from_yaml(text)
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ObservationSpecError(f"observation spec parameter is not valid YAML: {err}") from err
        return cls.from_dict(_observation_block(data))

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping; ``from_dict(to_dict())`` round-trips."""
        return {"step_topic": self.step_topic, "tolerance_s": float(self.tolerance_s),
                "wait_s": float(self.wait_s), "stamp": self.stamp,
                "fields": [f.to_dict() for f in self.fields]}


def _observation_block(data: Any) -> Any:
    """The spec mapping inside ``data``: itself, its ``observation:`` block, or the ``assemble:`` block
    of a reader spec (``reader:`` section or top level), so one YAML serves the reader and the node."""
    if not isinstance(data, Mapping):
        return data
    for key in ("observation", "assemble"):
        block = data.get(key)
        if isinstance(block, Mapping) and "fields" in block:
            return block
    if isinstance(data.get("reader"), Mapping):
        return _observation_block(data["reader"])
    return data


def resolve_name(name: str, namespace: str) -> str:
    """Absolute topic name: ``name`` if absolute, else ``name`` under ``namespace``."""
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/")
    return f"{ns.rstrip('/')}/{name}"


def _reject_unknown(at: str, data: Mapping[str, Any], known: set[str]) -> None:
    unknown = sorted(str(k) for k in set(data) - known)
    if unknown:
        raise ObservationSpecError(f"{at}: unknown key{'s' if len(unknown) > 1 else ''} {unknown}; "
                                   f"known: {sorted(known)}")


def _field_from_dict(index: int, item: Any) -> FieldSpec:
    at = f"fields[{index}]"
    if not isinstance(item, Mapping):
        raise ObservationSpecError(f"{at} must be a mapping with topic, type and field")
    _reject_unknown(at, item, {"topic", "type", "field", "names", "size"})
    for key in ("topic", "type", "field"):
        if key not in item:
            raise ObservationSpecError(f"{at}.{key} is missing")
    names = item.get("names")
    if names is not None and not isinstance(names, (list, tuple)):
        raise ObservationSpecError(f"{at}: names must be a list of names, got {names!r}")
    try:
        return FieldSpec(topic=item["topic"], type=item["type"], field=item["field"],
                         names=None if names is None else tuple(names), size=item.get("size"))
    except ObservationSpecError as err:
        raise ObservationSpecError(f"{at}: {err}") from err
