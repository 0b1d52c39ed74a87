"""The reader spec: which topics and types make up an episode, and how to align and split them.

The YAML form (``config/reader_*.yaml``) holds the same keys under an optional ``reader:`` key;
``ReaderSpec.from_yaml`` validates it and names the key at fault.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml

from ompn_ros import layout

from ..errors import ObservationSpecError, ReaderSpecError
from ..messages.fieldpath import FieldPathError, parse_path
from ..messages.types import full_name
from ..obs.spec import ObservationSpec

T = TypeVar("T")

OnError = Literal["raise", "skip_tail"]
LabelKind = Literal["ordinal", "id", "boundary", "none"]
FinalObservation = Literal["drop_last_step", "duplicate", "blank", "extrapolate", "require", "auto"]
Split = Literal["auto", "markers", "gaps", "topic", "idle", "bag"]
FINAL_OBSERVATION = ("drop_last_step", "duplicate", "blank", "extrapolate", "require", "auto")
FINAL_GUESSES: tuple[FinalObservation, ...] = ("duplicate", "blank", "extrapolate")
"""The options that guess row T of an episode without its final observation (what ``auto`` chooses
among; each keeps every recorded action)."""
DEFAULT_FINAL_OPTIONS: tuple[FinalObservation, ...] = ("extrapolate", "duplicate")
"""``final_options`` by default: the two guesses of a smooth continuous row T
(docs/design.md#final-observation-auto)."""
PRESET_FINAL: dict[str, FinalObservation] = {"craft": "blank", "dial": "auto"}
"""``final_observation`` of each domain's preset: Craft the option that lost least against complete
bags (docs/design.md#final-observation); Dial ``auto``, the choice on validation between
``extrapolate`` and ``duplicate`` (docs/design.md#final-observation-auto)."""
SPLITS = ("auto", "markers", "gaps", "topic", "idle", "bag")
VECTOR_TYPES = (layout.FLOAT32_ARRAY, layout.FLOAT64_ARRAY, layout.JOINT_STATE)
ACTION_TYPES = (layout.INT32, layout.FLOAT32_ARRAY, layout.FLOAT64_ARRAY, layout.JOINT_STATE)
"""The types read without a ``field`` path (the hand-written fast parsers); any other type is read
through a ``field`` path (:mod:`ompn_ros.data.messages.fieldpath`, docs/specs.md)."""
MARKER_TYPES = (layout.EPISODE_MARKER_TYPE, layout.DIAGNOSTIC_ARRAY)  # typed; string-keyed (deprecated)
SWITCH_TYPES = frozenset({"std_msgs/msg/Bool", "std_msgs/msg/String"} | {
    f"std_msgs/msg/{kind}{bits}" for kind in ("Int", "UInt") for bits in (8, 16, 32, 64)})
"""Types of a recording on/off topic (``ReaderSpec.split_topic``); any other type: each message starts
an episode."""


@dataclass(frozen=True)
class VectorSource:
    """Where a per-step vector comes from.

    Attributes:
        topic: topic name (relative names resolve in ``ReaderSpec.namespace``).
        type: ``Float32MultiArray``, ``Float64MultiArray`` (read as float32), ``JointState`` or
            (actions) ``Int32``; any other message type (``pkg/msg/Type``) with ``field``;
            ``None`` = as in the bag.
        field: a field path into the message (``positions``, ``gripper.width``, ``twist.linear``,
            ``points[-1].positions``; docs/specs.md): the numbers it leads to, in definition
            order, are the vector.  ``None``: the type's own vector (MultiArray ``data``,
            JointState ``fields``).
        dim: expected vector size (checked), ``None`` = the size of the topic's first message.
        fields: JointState fields concatenated in this order (``position``/``velocity``/``effort``).
        joint_names: JointState joint order (by name); ``None`` = the message's own order.
        merge_s: JointState messages of several publishers on this topic (arm and gripper drivers
            on one ``/joint_states``): merged by joint name, each of ``joint_names`` taking its
            latest value at or before the step if at most ``merge_s`` seconds older; the messages
            naming the first of ``joint_names`` are the steps (:mod:`ompn_ros.data.joint_merge`).
            Steps lacking a joint are dropped and counted (``BagReport.missing['<topic>[<joint>]']``).
            ``None`` = one publisher.
    """

    topic: str
    type: str | None = layout.FLOAT32_ARRAY
    dim: int | None = None
    fields: tuple[str, ...] = ("position",)
    joint_names: tuple[str, ...] | None = None
    merge_s: float | None = None
    field: str | None = None

    def __post_init__(self) -> None:
        if self.field is not None:
            self._check_field()
        if self.merge_s is not None and (self.merge_s < 0 or not self.joint_names):
            raise ReaderSpecError(f"topic '{self.topic}': merge_s needs joint_names (the first names the "
                                  f"step joint) and a value >= 0, got {self.merge_s}")
        bad = [f for f in self.fields if f not in layout.JOINT_FIELDS]
        if bad or not self.fields:
            raise ReaderSpecError(f"topic '{self.topic}': JointState fields must be a non-empty subset "
                                  f"of {layout.JOINT_FIELDS}, got {list(self.fields)}")
        if self.type is not None and self.type not in ACTION_TYPES and self.field is None:
            raise ReaderSpecError(f"topic '{self.topic}': type '{self.type}' needs a field path (key "
                                  f"'field', e.g. field: positions; docs/specs.md); without one the type "
                                  f"must be one of {ACTION_TYPES}")

    def _check_field(self) -> None:
        try:
            parse_path(self.field or "")
        except FieldPathError as err:
            raise ReaderSpecError(f"topic '{self.topic}': {err}") from None
        if self.type is not None:
            object.__setattr__(self, "type", full_name(self.type))
        if self.joint_names is not None or self.merge_s is not None:
            raise ReaderSpecError(f"topic '{self.topic}': joint_names and merge_s are JointState keys; with "
                                  "a field path give the field of the joints you want")

    @property
    def generic(self) -> bool:
        """Whether the vector is read through ``field`` (else by the type's fast parser)."""
        return self.field is not None


DEFAULT_OBSERVATION = VectorSource(layout.OBSERVATION)


@dataclass(frozen=True)
class ReaderSpec:
    """Which topics and types make up an episode, and how to align and split them.

    Attributes:
        observation, action: the per-step vectors (the action may come from the observation
            topic itself, e.g. ``JointState.velocity``: then every observation has its action).
        assemble: an observation made of named fields of one or more topics (YAML key
            ``assemble``: an :class:`~ompn_ros.data.obs.ObservationSpec` block, the form the live
            assembler takes); it replaces ``observation``.  The observations are those of
            :func:`~ompn_ros.data.obs.assemble_stream` over the bag's messages in record order (the
            live rule: the latest message of each topic at or before the step message, within
            ``tolerance_s``).  Every message of its ``step_topic`` is a step: the step clock is their
            log stamps (so ``stamp`` must be ``log``), actions and labels attach to it, then the
            steps the rule dropped are removed (counted by reason in ``BagReport.obs_dropped``).
            ``Episode.extras['obs_names']`` names the elements.  Relative topic names resolve like
            every other topic of the spec.
        subtask, sketch, episode, joint_states: optional topics (``None`` = not used; absent from
            a bag = not used).  ``joint_states`` fills ``Episode.extras['joint_*']``.
        namespace: resolves relative topic names; a relative name absent under it falls back to
            the unique bag topic ending in ``/<name>``.
        time_gap: seconds between observations that split episodes when there are no markers.
        tolerance: seconds a partner may follow its observation (see the alignment rule).
        strict: raise :class:`AlignmentError` on missing/duplicate partners instead of counting.
        stamp: ``'log'`` (bag stamps) or ``'header'`` (``header.stamp`` of JointState topics and of
            the topics read through a field path whose type has a ``std_msgs/Header header``;
            meant for foreign bags whose per-step topics are all stamped on one clock).
        stamps: the time base per topic (YAML key ``stamps``, ``{topic: log | header}``), overriding
            ``stamp`` for the topics it names; ``header`` needs a JointState topic or a field-path
            topic with a header.  Partners are
            aligned on these stamps, so topics stamped on different clocks (the robot's header
            stamps, a label node's receive time) must be brought to one: when most messages of a
            partner attach to no observation while its stamps and the observations' are offset by a
            constant, the read stops with one line naming both topics and the offset
            (:mod:`ompn_ros.data.reader.clocks`).
        task: task name for episodes without a start marker.
        labels: what the ``subtask`` topic holds (YAML key ``labels``):

            * ``ordinal``: an ``Int32`` per step, the 0-based subtask ordinal within the episode
              (our sims).  Values must not decrease within an episode (nor reach the sketch
              length); otherwise :class:`LabelError` names the episode and suggests ``id``.
            * ``id``: an ``Int32`` per step holding a skill id (e.g. 17, 4, 4, 9).  Ordinals are
              derived from changes, equal consecutive ids stay one subtask; the ids are kept in
              ``Episode.extras['subtask_id']``.
            * ``boundary``: an event topic of any type; a message marks the step it attaches to
              (alignment rule) as the last step of a subtask.
            * ``none``: no labels are read.
            * ``None`` (default): ``ordinal`` when the topic is in the bag, no labels otherwise.

            ``ordinal``, ``id`` and ``boundary`` require the topic (:class:`MissingTopicError`).
            Metrics only ever see the ordinals (``Episode.subtask``).

            ``subtask`` may also be a mapping ``{topic, type, field}`` (the grammar of
            ``observation`` and ``action``, docs/specs.md): the label is the number or string
            ``field`` leads to in any message type (``task_msgs/msg/Skill`` ``id``,
            ``std_msgs/msg/String`` ``data``).  Strings are names: with ``labels: id`` each distinct
            name gets an id in order of first appearance (``BagReport.notes`` lists them).
        final_observation: what to do with an episode whose last observation already has an
            action, i.e. the observation after the last command was not recorded (YAML key
            ``final_observation``):

            * ``duplicate`` (default): the last observation is repeated as row ``T``
              (``s_{T+1} = s_T``); every recorded action is kept.
            * ``blank``: row ``T`` is all zeros, an input no real observation gives, so the
              'done' step (paper §3.2) is learned at an observation of its own; every recorded
              action is kept.  The Craft preset (:meth:`for_domain`) uses it.
            * ``extrapolate``: row ``T`` is ``2 s_T - s_{T-1}``, a linear guess of the missing
              observation from the last two (an episode of one step gets a duplicate); every
              recorded action is kept.  Meant for smooth continuous states (joint positions and
              velocities), not one-hot features.
            * ``drop_last_step``: the last observation becomes row ``T`` and its action step is
              dropped (one step per episode is lost; when that step completes the task, as Craft's
              final ``use`` does, the model learns to stop early).
            * ``require``: such an episode is an :class:`AlignmentError` (``strict``) or dropped.
            * ``auto``: ``ompn_train`` trains once per option of ``final_options`` on the same
              split and keeps the run whose online detector validation prefers
              (:mod:`ompn_ros.app.final_choice`, docs/design.md#final-observation-auto); a replay
              reads with the option its checkpoint names (:mod:`ompn_ros.app.final_record`),
              anything else with the first option.  The Dial preset uses it.

            How each option fares against complete bags, and why ``ompn_train`` keeps the better
            of two runs on such bags (``train.candidates_no_final``): docs/design.md#final-observation.
            Record the observation after the last command when you can.

            The report lists the episodes each handling applied to (``BagReport.adjusted``).
        final_options: the options ``final_observation: auto`` tries, in order (at least one, each
            of ``duplicate``, ``blank``, ``extrapolate``, no repeats).  The first
            is kept when validation cannot choose (no labels) and is what other readers use.
        split: how episodes are delimited (YAML key ``split``): ``markers`` (start/end markers on
            the ``episode`` topic, required), ``gaps`` (observations more than ``time_gap``
            seconds apart), ``topic`` (every message on ``split_topic`` starts an episode at the
            next observation; observations before the first one are not used), ``idle`` (the
            robot is idle for ``idle_s``: :mod:`ompn_ros.data.cuts.idle`, the rule ``ompn_node``'s
            ``idle_s`` applies live), ``bag`` (one bag per demonstration: each bag of a folder is
            one episode) or ``auto`` (default: markers when the bag has any, else gaps).
        split_topic: the topic for ``split: topic``.  A recording switch marks on and off: a
            ``std_msgs`` ``Bool``, an integer (``Int*``/``UInt*``) holding only 0 and 1, or a
            ``String`` holding only on/off words (``start on true 1 record begin`` /
            ``stop off false 0 pause end``); on starts an episode, off ends it (observations while
            off are not used).  Any other topic: every message starts an episode (stamps only).
        idle_s: ``split: idle``: seconds the robot must be idle to end an episode (> 0).
        idle_speed: ``split: idle``: a step is idle when its speed is below this: the joint speed
            of a JointState observation (positions' change per second and measured velocities, rad/s
            for revolute joints; efforts ignored), any element's change per second otherwise
            (:class:`ompn_ros.data.cuts.SpeedElements`).  ``auto`` (default): derived per bag from its
            own noise floor and named in the read report (:func:`ompn_ros.data.cuts.derive_idle_speed`);
            0 = never by speed.  A step with no command attached (an action topic other than the
            observation's) is idle as well.
        types: where message types come from beyond ROS 2 Jazzy's and the bag's own definitions
            (rosbags stores them in the bag; older bags lack them): folders of ``.msg`` files
            (``<pkg>/msg/<Name>.msg`` below each) or installed interface package names
            (:mod:`ompn_ros.data.messages.types`, docs/specs.md).
    """

    observation: VectorSource = DEFAULT_OBSERVATION
    assemble: ObservationSpec | None = None
    action: VectorSource = VectorSource(layout.ACTION, type=None)
    subtask: str | None = layout.SUBTASK
    sketch: str | None = layout.SKETCH
    episode: str | None = layout.EPISODE
    joint_states: str | None = None
    namespace: str = "/"
    time_gap: float = 0.5
    tolerance: float = 5.0
    strict: bool = False
    stamp: Literal["log", "header"] = "log"
    stamps: tuple[tuple[str, Literal["log", "header"]], ...] | None = None  # a mapping is accepted
    task: str = ""
    labels: LabelKind | None = None
    final_observation: FinalObservation = "duplicate"
    final_options: tuple[FinalObservation, ...] = DEFAULT_FINAL_OPTIONS  # a list is accepted
    split: Split = "auto"
    split_topic: str | None = None
    idle_s: float = 1.0
    idle_speed: float | Literal["auto"] = "auto"
    types: tuple[str, ...] = ()  # a list is accepted
    subtask_type: str | None = None  # YAML: subtask: {topic, type, field}
    subtask_field: str | None = None

    def __post_init__(self) -> None:
        normal = _check_choices(self)
        normal["types"] = _type_sources(self.types)
        if not self.observation.generic and self.observation.type not in VECTOR_TYPES:
            raise ReaderSpecError(f"observation type must be one of {VECTOR_TYPES}, "
                                  f"got '{self.observation.type}'")
        if self.time_gap <= 0 or self.tolerance < 0:
            raise ReaderSpecError(f"time_gap must be > 0 and tolerance >= 0 (got {self.time_gap}, "
                                  f"{self.tolerance})")
        if self.stamp not in ("log", "header"):
            raise ReaderSpecError(f"stamp must be 'log' or 'header', got '{self.stamp}'")
        if self.stamps is not None:
            normal["stamps"] = _stamp_pairs(self.stamps)
        for key, value in normal.items():  # the normal forms of the keys given loosely (lists, mappings)
            object.__setattr__(self, key, value)
        if self.assemble is not None:
            _check_assemble(self)

    @property
    def final_guess(self) -> FinalObservation:
        """The option the reader applies: ``final_observation``, or the first of ``final_options`` for
        ``auto`` (``ompn_train`` reads once per option instead, :meth:`with_final`)."""
        return self.final_options[0] if self.final_observation == "auto" else self.final_observation

    def with_final(self, option: FinalObservation) -> ReaderSpec:
        """This spec reading with ``option`` (one of ``final_options``) in place of ``auto``."""
        if option not in self.final_options:
            raise ReaderSpecError(f"final option '{option}' is not one of final_options {self.final_options}")
        return replace(self, final_observation=option)

    @classmethod
    def for_domain(cls, domain: str | layout.DomainLayout) -> ReaderSpec:
        """The preset for our own sims' bags (same as ``config/reader_<domain>.yaml``); its
        ``final_observation`` is the option measured best on that domain (:data:`PRESET_FINAL`)."""
        dom = layout.DOMAINS[domain] if isinstance(domain, str) else domain
        return cls(
            observation=VectorSource(layout.OBSERVATION, layout.FLOAT32_ARRAY, dom.obs_dim),
            action=VectorSource(layout.ACTION, dom.action_msg,
                                None if dom.action_type == "discrete" else dom.action_dim),
            joint_states=layout.JOINT_STATES if dom.has_joint_states else None,
            strict=True,
            final_observation=PRESET_FINAL.get(dom.name, "duplicate"),
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ReaderSpec:
        """Build from a mapping (the YAML form; an outer ``reader:`` key is accepted)."""
        if set(data) == {"reader"}:
            data = data["reader"]
        known = set(cls.__dataclass_fields__)
        unknown = set(data) - known
        if unknown:
            raise ReaderSpecError(f"unknown reader spec keys {sorted(unknown)}; known: {sorted(known)}")
        return _build(cls, _parsed_sections(data), "reader spec")

    @classmethod
    def from_yaml(cls, path: str | Path) -> ReaderSpec:
        """Load a spec from a YAML file (see ``config/reader_*.yaml``)."""
        with open(path, encoding="utf-8") as fh:
            try:
                data = yaml.safe_load(fh)
            except (UnicodeDecodeError, yaml.YAMLError) as err:
                raise ReaderSpecError(f"reader spec file '{path}' is not valid YAML: {err}") from err
        if not isinstance(data, dict):
            raise ReaderSpecError(f"reader spec file '{path}' must hold a mapping")
        try:
            return cls.from_dict(data)
        except ReaderSpecError as err:
            raise ReaderSpecError(f"{path}: {err}") from err

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (JSON/YAML friendly); ``from_dict(to_dict())`` round-trips."""
        out = asdict(self)
        for key in ("observation", "action"):
            out[key] = _plain_source(out[key])
        out["assemble"] = None if self.assemble is None else self.assemble.to_dict()
        out["stamps"] = None if self.stamps is None else dict(self.stamps)
        out["final_options"] = list(self.final_options)
        # the new keys only when used: a spec without them keeps its former form (and cache keys)
        if self.types:
            out["types"] = list(self.types)
        else:
            del out["types"]
        if self.subtask_field is not None:
            out["subtask"] = {"topic": self.subtask, "type": self.subtask_type, "field": self.subtask_field}
        del out["subtask_type"], out["subtask_field"]
        return out


# --- one key or section at a time: the checks and the normal forms of ReaderSpec's keys --------------
def _check_choices(spec: ReaderSpec) -> dict[str, Any]:
    """Check the choice keys (labels, final observation, split) in a fixed order, the first fault
    named; returns the normal forms of ``final_options`` and ``idle_speed``."""
    if spec.labels is not None and spec.labels not in layout.LABEL_KINDS:
        raise ReaderSpecError(f"labels must be one of {layout.LABEL_KINDS}, got '{spec.labels}'")
    if spec.final_observation not in FINAL_OBSERVATION:
        raise ReaderSpecError(f"final_observation must be one of {FINAL_OBSERVATION}, "
                              f"got '{spec.final_observation}'")
    normal: dict[str, Any] = {"final_options": _final_options(spec.final_options)}
    if spec.split not in SPLITS:
        raise ReaderSpecError(f"split must be one of {SPLITS}, got '{spec.split}'")
    if spec.split == "topic" and not spec.split_topic:
        raise ReaderSpecError("split: topic needs split_topic (the topic whose messages start episodes)")
    normal["idle_speed"] = _idle_speed(spec.idle_speed)
    if spec.idle_s <= 0:
        raise ReaderSpecError(f"idle_s must be > 0 (got {spec.idle_s})")
    if spec.split == "markers" and not spec.episode:
        raise ReaderSpecError("split: markers needs the episode topic (key 'episode')")
    if spec.labels in ("ordinal", "id", "boundary") and not spec.subtask:
        raise ReaderSpecError(f"labels: {spec.labels} needs the subtask topic (key 'subtask')")
    return normal


def _final_options(value: Any) -> tuple[FinalObservation, ...]:
    """``final_options`` as a tuple of distinct guessing options (a list is accepted)."""
    options = tuple(value) if isinstance(value, (list, tuple)) else (value,)
    bad = [o for o in options if o not in FINAL_GUESSES]
    if not options or bad or len(set(options)) != len(options):
        raise ReaderSpecError(f"final_options must list distinct options of {FINAL_GUESSES}, "
                              f"got {value!r}")
    return options


def _idle_speed(speed: Any) -> float | Literal["auto"]:
    """``idle_speed``: ``'auto'`` (any case, spaces around) or a number >= 0."""
    if isinstance(speed, str):
        if speed.strip().lower() != "auto":
            raise ReaderSpecError(f"idle_speed must be 'auto' (from the bag's noise floor) or a number "
                                  f">= 0 (rad/s of joint speed; 0 = never by speed), got {speed!r}")
        return "auto"
    if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not speed >= 0:
        raise ReaderSpecError(f"idle_speed must be 'auto' or a number >= 0, got {speed!r}")
    return speed


def _type_sources(value: Any) -> tuple[str, ...]:
    """``types`` as a tuple of non-empty strings (folders of ``.msg`` files or package names)."""
    sources = (value,) if isinstance(value, str) else tuple(value or ())
    if not all(isinstance(v, str) and v.strip() for v in sources):
        raise ReaderSpecError(f"types must list folders of .msg files or interface package names, "
                              f"got {value!r}")
    return sources


def _stamp_pairs(value: Any) -> tuple[tuple[str, Literal["log", "header"]], ...]:
    """``stamps`` as sorted ``(topic, base)`` pairs (the spec stays hashable); a mapping is accepted."""
    try:
        pairs = tuple(sorted(dict(value).items()))
    except (TypeError, ValueError):
        raise ReaderSpecError(f"stamps must map topics to 'log' or 'header', got {value!r}") from None
    bad = {k: v for k, v in pairs if v not in ("log", "header")}
    if bad:
        raise ReaderSpecError(f"stamps: each topic's time base must be 'log' or 'header', got {bad}")
    return pairs


def _check_assemble(spec: ReaderSpec) -> None:
    if not isinstance(spec.assemble, ObservationSpec):
        raise ReaderSpecError(f"assemble must be an ObservationSpec, got {type(spec.assemble).__name__}")
    if spec.observation != DEFAULT_OBSERVATION:
        raise ReaderSpecError("give either 'observation' (one topic) or 'assemble' (named fields of "
                              "several topics), not both")
    if spec.stamp != "log" or spec.stamps:
        raise ReaderSpecError("with 'assemble' the step clock is the bag's log stamps: set stamp: log "
                              "and no stamps (assemble's own 'stamp' key chooses the stamps of its rule)")


def _parsed_sections(data: dict[str, Any]) -> dict[str, Any]:
    """The keyword arguments of a spec mapping, its sections (``observation``, ``action``, ``subtask``
    as a mapping, ``assemble``) parsed into their classes."""
    kwargs = dict(data)
    for key in ("observation", "action"):
        if key in kwargs:
            kwargs[key] = _vector_source(key, kwargs[key])
    if isinstance(kwargs.get("subtask"), dict):
        label = _vector_source("subtask", kwargs["subtask"])
        if label.field is None:
            raise ReaderSpecError("'subtask' as a mapping needs 'field' (e.g. {topic: /skill, type: "
                                  "std_msgs/msg/String, field: data})")
        kwargs.update(subtask=label.topic, subtask_type=label.type, subtask_field=label.field)
    if kwargs.get("assemble") is not None:
        kwargs["assemble"] = _observation_spec(kwargs["assemble"])
    return kwargs


def _plain_source(src: dict[str, Any]) -> dict[str, Any]:
    """A :class:`VectorSource` of ``asdict`` in its YAML form (lists; ``field`` only when used)."""
    src["fields"] = list(src["fields"])
    src["joint_names"] = None if src["joint_names"] is None else list(src["joint_names"])
    if src["field"] is None:
        del src["field"]
    return src


def _observation_spec(value: Any) -> ObservationSpec:
    if isinstance(value, ObservationSpec):
        return value
    try:
        return ObservationSpec.from_dict(value)
    except ObservationSpecError as err:
        raise ReaderSpecError(f"assemble: {err}") from err


def _vector_source(key: str, value: Any) -> VectorSource:
    if isinstance(value, VectorSource):
        return value
    if isinstance(value, str):
        return VectorSource(value)
    if not isinstance(value, dict) or "topic" not in value:
        raise ReaderSpecError(f"'{key}' must be a topic name or a mapping with a 'topic' key")
    value = dict(value)
    if "fields" in value:
        value["fields"] = tuple(value["fields"])
    if value.get("joint_names") is not None:
        value["joint_names"] = tuple(value["joint_names"])
    return _build(VectorSource, value, f"'{key}' entry")


def _build(kind: Callable[..., T], kwargs: dict[str, Any], what: str) -> T:
    """``kind(**kwargs)``; a missing or unknown key raises :class:`ReaderSpecError` ``bad <what>: ...``."""
    try:
        return kind(**kwargs)
    except TypeError as err:
        raise ReaderSpecError(f"bad {what}: {err}") from err
