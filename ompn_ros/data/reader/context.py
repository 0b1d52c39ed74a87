"""One bag's resolved topics and its stamps, with errors naming the file (its type checks:
:mod:`.type_checks`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ompn_ros import layout
from ompn_ros.layout import resolve_topic

from .. import messages as m
from ..errors import MissingTopicError, TopicTypeError
from ..messages.fieldpath import NAME, fields_of
from ..messages.types import known
from ..obs.spec import ObservationSpec
from .raw import RawBag
from .report import BagReport
from .spec import ACTION_TYPES, MARKER_TYPES, VECTOR_TYPES, ReaderSpec, VectorSource
from .type_checks import TypeChecks


@dataclass(frozen=True)
class Topics:
    """Bag topic names the spec resolved to (``None`` = not used)."""

    obs: str
    act: str
    obs_type: str
    act_type: str
    sub: str | None = None
    sketch: str | None = None
    episode: str | None = None
    joints: str | None = None
    split: str | None = None
    labels: str = layout.LABELS_NONE  # the effective label kind ('none' when there is no topic)
    assemble: ObservationSpec | None = None  # ReaderSpec.assemble with the bag's topic names

    def used(self) -> list[str]:
        names = (self.obs, self.act, self.sub, self.sketch, self.episode, self.joints, self.split)
        partners = self.assemble.partner_topics if self.assemble is not None else ()
        return sorted({t for t in (*names, *partners) if t})


class BagContext:
    """Resolved topics of one bag and helpers naming the file in errors."""

    def __init__(self, raw: RawBag, spec: ReaderSpec, report: BagReport, name: Path | None = None,
                 joint_orders: dict[str, tuple[str, ...]] | None = None) -> None:
        self.raw = raw
        self.spec = spec
        self.report = report
        self.path = str(name if name is not None else raw.path)  # in errors: the user's bag
        self.checks = TypeChecks(raw, spec.types, self.path)  # does the spec read the topics' types
        self._clocks: dict[str, str] = {}  # ReaderSpec.stamps by bag topic (resolve_all)
        self.header_lag: dict[str, np.ndarray] = {}  # header-stamped topic -> log - header stamps (ns)
        # JointState topic -> the joint order its first message fixed (shared by the bags of one read)
        self.joint_orders: dict[str, tuple[str, ...]] = {} if joint_orders is None else joint_orders

    def clock(self, topic: str) -> str:
        """The time base of ``topic``: ``ReaderSpec.stamps`` for it, else ``ReaderSpec.stamp``; topics
        without a header the reader uses (all but JointState and the types read through a field path
        that have a ``header``) are always on the bag's receive clock."""
        if not self._has_header(topic):
            return "log"
        return self._clocks.get(topic, self.spec.stamp)

    def _has_header(self, topic: str) -> bool:
        """Whether the reader can take ``header.stamp`` of every message of ``topic`` (a topic under
        several types: of each type)."""
        types = self.raw.topic_types(topic)
        return bool(types) and (all(t == layout.JOINT_STATE for t in types) or self._generic_header(topic))

    def _generic_header(self, topic: str) -> bool:
        """Whether ``topic`` is read through a field path and each of its types has ``header.stamp``."""
        spec = self.spec
        sources = [s for s in (spec.observation, spec.action) if s.field is not None
                   and self.resolve_quiet(s.topic) == topic]
        types = self.raw.topic_types(topic)
        if not sources or not types or not all(known(t) for t in types):
            return False
        return all(dict(fields_of(t)).get("header") == (NAME, "std_msgs/msg/Header") for t in types)

    def resolve_quiet(self, name: str) -> str:
        """``name`` resolved in the spec's namespace (no suffix match, no note)."""
        return resolve_topic(name, self.spec.namespace)

    def message_types(self, topic: str) -> list[str]:
        """Each message's type in the topic's (sorted) order."""
        self.stamps(topic)
        tdata = self.raw.topics.get(topic)
        return [] if tdata is None else tdata.message_types()

    def resolve(self, name: str | None, required: bool) -> str | None:
        """Bag topic of spec name ``name``; a unique ``/<name>`` suffix match is noted."""
        if name is None:
            return None
        topic = resolve_topic(name, self.spec.namespace)
        if topic in self.raw.types:
            return topic
        if not name.startswith("/"):
            candidates = [t for t in self.raw.types if t.endswith("/" + name)]
            if len(candidates) == 1:
                self.report.notes.append(f"topic '{name}' resolved to '{candidates[0]}'")
                self.report.guessed.append(f"topic '{name}' = '{candidates[0]}' (unique suffix match)")
                return candidates[0]
        if required:
            raise MissingTopicError(f"required topic not in bag (bag topics: {sorted(self.raw.types)})",
                                    path=self.path, topic=topic)
        self.report.notes.append(f"spec topic '{name}' ({topic}) is not in the bag: not used")
        return None

    def _episode_topic(self) -> str | None:
        """The episode markers' topic: with the spec's default name (``episode``), the typed
        ``episode_marker`` when the bag has it; otherwise the topic the spec names."""
        spec = self.spec
        if spec.episode == layout.EPISODE:
            typed = resolve_topic(layout.EPISODE_MARKER, spec.namespace)
            suffixed = [t for t in self.raw.types if t.endswith("/" + layout.EPISODE_MARKER)]
            if typed in self.raw.types or len(suffixed) == 1:
                return self.resolve(layout.EPISODE_MARKER, False)
        return self.resolve(spec.episode, spec.split == "markers")

    def resolve_all(self) -> Topics:
        """Resolve and type-check every topic of the spec (raises on a missing required one)."""
        spec = self.spec
        assemble = self._resolve_assemble()
        obs = assemble.step_topic if assemble is not None else self.resolve(spec.observation.topic, True)
        act = self.resolve(spec.action.topic, True)
        assert obs is not None and act is not None  # required=True raised otherwise
        sub, labels = self._label_topic()
        topics = Topics(
            obs=obs, act=act, assemble=assemble,
            obs_type=self.raw.types[obs] if assemble is not None else
            self.checks.check_source(obs, spec.observation, VECTOR_TYPES),
            act_type=self.checks.check_source(act, spec.action, ACTION_TYPES),
            sub=sub, labels=labels,
            sketch=self.resolve(spec.sketch, False),
            episode=self._episode_topic(),
            joints=self.resolve(spec.joint_states, False),
            split=self.resolve(spec.split_topic, True) if spec.split == "topic" else None,
        )
        if topics.split:
            self.checks.check_switch(topics.split)
        for topic, kind in ((topics.sketch, layout.INT32_ARRAY), (topics.joints, layout.JOINT_STATE)):
            if topic:
                self.checks.check_type(topic, (kind,), kind)
        if topics.episode:  # the typed marker, or the DiagnosticArray form (deprecated, still read)
            m.register_interfaces()
            self.checks.check_type(topics.episode, MARKER_TYPES, None)
        if sub and labels != layout.LABELS_BOUNDARY:  # boundary events: only stamps are used
            if spec.subtask_field is not None:
                label = VectorSource(sub, spec.subtask_type, field=spec.subtask_field)
                self.checks.check_source(sub, label, (), strings=True)
            else:  # a topic under several types is checked message type by message type
                self.checks.check_source(sub, VectorSource(sub, layout.INT32), (layout.INT32,))
        for name, base in self.spec.stamps or ():
            topic = self.resolve(name, False)  # like every topic of the spec; absent: noted, not used
            if topic is not None:
                self._clocks[topic] = base
        for topic, clock in self._clocks.items():
            if clock == "header" and not self._has_header(topic):
                types = " and ".join(self.raw.topic_types(topic))
                raise TopicTypeError(f"'{types}' has no header stamp the reader uses: set its time base "
                                     "to log in the reader spec's stamps", path=self.path, topic=topic,
                                     index=0)
        return topics

    def _resolve_assemble(self) -> ObservationSpec | None:
        """``spec.assemble`` with bag topic names; each topic resolved (required) and type-checked."""
        asm = self.spec.assemble
        if asm is None:
            return None
        names: dict[str, str] = {}
        for name, want in asm.topics.items():
            topic = self.resolve(name, True)
            assert topic is not None  # required=True raised otherwise
            self.checks.check_assembled(topic, asm, name, want)
            names[name] = topic
        fields = tuple(replace(f, topic=names[f.topic]) for f in asm.fields)
        return replace(asm, step_topic=names[asm.step_topic], fields=fields)

    def _label_topic(self) -> tuple[str | None, str]:
        """The subtask topic and the effective label kind (``labels: None`` = ordinal if present)."""
        kind = self.spec.labels
        if kind == layout.LABELS_NONE:
            return None, layout.LABELS_NONE
        topic = self.resolve(self.spec.subtask, kind is not None)
        if topic is None:
            return None, layout.LABELS_NONE
        return topic, kind or layout.LABELS_ORDINAL

    def stamps(self, topic: str) -> np.ndarray:
        """Stamps (int64, sorted) of ``topic``; its messages are put in the same order (stable)."""
        tdata = self.raw.topics.get(topic)
        if tdata is None:
            return np.zeros(0, dtype=np.int64)
        stamps = np.asarray(tdata.stamps, dtype=np.int64)
        if stamps.size > 1 and np.any(np.diff(stamps) < 0):
            order = np.argsort(stamps, kind="stable")
            tdata.keep(order.tolist())
            stamps = stamps[order]
        return stamps

    def data(self, topic: str) -> tuple[np.ndarray, list[bytes]]:
        """Stamps (int64, sorted) and raw messages of ``topic`` (a column decoded while reading is
        turned back into its exact bytes)."""
        stamps = self.stamps(topic)
        tdata = self.raw.topics.get(topic)
        if tdata is None:
            return stamps, []
        if tdata.column is not None:
            tdata.raws, tdata.column = tdata.column.to_raws(), None
        if not tdata.has_raws:
            raise RuntimeError(f"{self.path}: the bytes of topic '{topic}' were not kept while reading")
        return stamps, tdata.raws

    def column(self, topic: str) -> tuple[np.ndarray, np.ndarray] | None:
        """Sorted stamps and float32 rows of ``topic`` when it was decoded while reading, else ``None``."""
        tdata = self.raw.topics.get(topic)
        if tdata is None or tdata.column is None:
            return None
        stamps = self.stamps(topic)
        assert tdata.column is not None  # stamps() reorders the column, never drops it
        return stamps, tdata.column.values
