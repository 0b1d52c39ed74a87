"""Whether the reader spec reads every type a bag's topics carry, with errors naming the file.

A topic recorded under several types (a split bag where a driver changed its message) is read
message type by message type where each type fits the spec; otherwise one line names both types,
the message where the change happens and the way out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from ompn_ros import layout

from .. import messages as m
from ..errors import ObservationSpecError, TopicTypeError, UnknownTypeError
from ..messages.fieldpath import FieldPathError, describe
from ..messages.types import TypeDefinitionError, ensure, known
from ..obs.spec import ObservationSpec, canonical_type
from .raw import RawBag
from .spec import SWITCH_TYPES, VectorSource


class TypeChecks:
    """The type checks of one bag's topics against the spec's roles (``types``: ``ReaderSpec.types``,
    where message types come from; ``path``: the bag named in errors)."""

    def __init__(self, raw: RawBag, types: tuple[str, ...], path: str) -> None:
        self.raw = raw
        self.types = types
        self.path = path

    def check_source(self, topic: str, src: VectorSource, allowed: Sequence[str],
                     strings: bool = False) -> str:
        """The type of ``topic`` after checking ``src`` reads every type it carries: the fast types
        without a field path, any registered type with one (one line naming the way out otherwise)."""
        types = self.raw.topic_types(topic)
        if len(types) == 1 and src.field is None:
            return self.check_type(topic, allowed, src.type)
        unfit = {t: self._unfit(t, src, tuple(allowed), strings) for t in types}
        why = {t: reason for t, reason in unfit.items() if reason is not None}
        if not why:
            return types[0]
        if len(types) == 1:
            raise (UnknownTypeError if not known(types[0]) else TopicTypeError)(
                why[types[0]], path=self.path, topic=topic, index=0)
        raise self._type_change(topic, types, why)

    def _unfit(self, msgtype: str, src: VectorSource, allowed: tuple[str, ...], strings: bool) -> str | None:
        """Why ``src`` cannot read messages of ``msgtype`` (``None``: it can)."""
        if src.field is not None:
            if src.type is not None and msgtype != src.type:
                return f"the spec's type is {src.type}"
            try:
                ensure(msgtype, self.types)
                target = describe(msgtype, src.field)
            except (TypeDefinitionError, FieldPathError) as err:
                return str(err)
            if target.kind == "string" and not strings:
                return f"field '{src.field}' of {msgtype} is a string"
            if strings and target.labels != ("",):
                return f"field '{src.field}' of {msgtype} is not one number or string (a label is one value)"
            return None
        if src.type is not None:
            return None if msgtype == src.type else f"the spec's type is {src.type}"
        if msgtype not in (layout.FLOAT32_ARRAY, layout.FLOAT64_ARRAY) or msgtype not in allowed:
            return f"without a field path a topic of several types must hold {layout.FLOAT32_ARRAY} or " \
                   f"{layout.FLOAT64_ARRAY}"
        return None

    def _type_change(self, topic: str, types: list[str], why: dict[str, str],
                     way_out: str = "give a field path both types have, or read the parts as separate "
                                    "bags") -> TopicTypeError:
        """The one line of a topic recorded under several types that the spec reads only some of."""
        tdata = self.raw.topics[topic]
        assert tdata.kinds is not None  # several types
        change = next(i for i, k in enumerate(tdata.kinds) if k != tdata.kinds[0])
        before, after = tdata.types[tdata.kinds[0]], tdata.types[tdata.kinds[change]]
        good = [t for t in types if t not in why]
        bad = [t for t in types if t in why]
        return TopicTypeError(
            f"the topic changes type from {before} to {after} at message #{change} (stamp "
            f"{tdata.stamps[change] / 1e9:.3f} s); the reader spec fits {' and '.join(good) or 'neither'}, "
            f"not {' and '.join(bad)} ({why[bad[0]]}): {way_out}", path=self.path, topic=topic, index=change,
            stamp=None)

    def check_switch(self, topic: str) -> None:
        """A recording on/off topic under several types: all switch types (each message read by its
        own) or none (each message an episode start); a mix is refused in one line."""
        types = self.raw.topic_types(topic)
        switch = [t for t in types if t in SWITCH_TYPES]
        if switch and len(switch) < len(types):
            why = {t: f"its messages would start episodes while those of {switch[0]} switch recording on "
                      "and off" for t in types if t not in SWITCH_TYPES}
            raise self._type_change(topic, types, why, way_out="read the parts as separate bags")

    def check_assembled(self, topic: str, asm: ObservationSpec, name: str, want: str) -> None:
        """Bag topic ``topic`` can give the assemble block's fields of its topic ``name`` (type ``want``)."""
        got = self.raw.types[topic]
        try:
            ensure(got, self.types)
        except TypeDefinitionError as err:
            raise UnknownTypeError(str(err), path=self.path, topic=topic, index=0) from None
        types = self.raw.topic_types(topic)
        if want not in [canonical_type(t) for t in types]:
            raise TopicTypeError(f"carries '{' and '.join(types)}', the reader spec's assemble block "
                                 f"expects '{want}'", path=self.path, topic=topic, index=0)
        why = {t: reason for t in types if (reason := self._assemble_unfit(asm, name, t)) is not None}
        if why:  # a topic under several types: each is read by its own type where the fields fit
            raise self._type_change(topic, types, why)

    def _assemble_unfit(self, asm: ObservationSpec, name: str, msgtype: str) -> str | None:
        """Why messages of ``msgtype`` cannot give the assemble block's fields of topic ``name``
        (``None``: they can; the spec's own type always can)."""
        if canonical_type(msgtype) == asm.type_of(name):
            return None
        try:
            ensure(msgtype, self.types)
            for f in asm.fields:
                if f.topic == name:
                    replace(f, type=msgtype)  # checks the field (path) against the type
        except (TypeDefinitionError, ObservationSpecError) as err:
            return str(err)
        return None

    def check_type(self, topic: str, allowed: Sequence[str], expected: str | None) -> str:
        """The topic's message type, after checking it is decodable and what the spec expects; a topic
        recorded under several types must have each fit (each message is decoded by its own type),
        else one line names both types and where the change happens."""
        types = self.raw.topic_types(topic)
        if len(types) > 1:
            why = {t: reason for t in types if (reason := self._type_unfit(t, allowed, expected)) is not None}
            if why:
                raise self._type_change(topic, types, why, way_out="read the parts as separate bags")
            return types[0]
        msgtype = self.raw.types[topic]
        reason = self._type_unfit(msgtype, allowed, expected)
        if reason is not None:
            kind = UnknownTypeError if msgtype not in m.typestore().types else TopicTypeError
            raise kind(reason, path=self.path, topic=topic, index=0)
        return msgtype

    @staticmethod
    def _type_unfit(msgtype: str, allowed: Sequence[str], expected: str | None) -> str | None:
        """Why a topic role of ``allowed`` types (``expected``: the spec's) cannot take ``msgtype``."""
        if msgtype not in m.typestore().types:
            return (f"message type '{msgtype}' is not in the ROS 2 Jazzy typestore nor the bag's "
                    "definitions: name its .msg folder with `types: DIR` in the reader spec and read a field "
                    "of it with `field:` (docs/specs.md)")
        if expected is not None and msgtype != expected:
            return f"carries '{msgtype}', the reader spec expects '{expected}'"
        if msgtype not in allowed:
            return f"carries '{msgtype}', expected one of {list(allowed)}"
        return None
