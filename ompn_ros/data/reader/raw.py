"""Messages of the wanted topics: the normal read through ``rosbags``.

Raw CDR is kept and decoded per topic in bulk afterwards, except for the step topic when a
:class:`StreamPlan` says so: its messages are decoded into one array as they are read
(:mod:`ompn_ros.data.reader.columns`) and their bytes dropped.  Cost: one pass over the bag's storage;
memory O(bytes of the raw-kept topics) plus the step array (about the bytes of the step topic).
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2 import Reader

from ..cuts import Repeats, unrepeated
from ..errors import CorruptBagError, UnknownTypeError
from ..messages.types import TypeDefinitionError, builtin, register_definition
from ..obs import ObservationSpec
from .columns import AssemblySink, Float32Column
from .compressed import NOTE as compressed_note
from .compressed import decompress, is_compressed
from .paths import storage_files


@dataclass(frozen=True)
class StreamPlan:
    """What to decode while reading (bag topic names).

    Attributes:
        column: a ``Float32MultiArray`` observation topic to decode into a :class:`Float32Column`.
        dim: the spec's observation size for ``column`` (``None``: the first message's).
        act_column: a ``Float32MultiArray`` action topic of its own, decoded the same way (its bytes
            would otherwise be held beside their decoded copy: the reader's peak memory).
        act_dim: the spec's action size for ``act_column``.
        assemble: ``ReaderSpec.assemble`` with bag topic names, fed to an :class:`AssemblySink`.
        keep_raw: topics whose raw bytes are still needed (e.g. a partner topic that is also the
            action topic); every other topic of the plan keeps stamps and record positions only.
    """

    column: str | None = None
    dim: int | None = None
    act_column: str | None = None
    act_dim: int | None = None
    assemble: ObservationSpec | None = None
    keep_raw: frozenset[str] = frozenset()


@dataclass
class TopicData:
    """Stamps (ns, as read), raw CDR messages and record positions (``seqs``: the message's index
    in the bag's record order, across topics) of one topic.  Stamps and positions are packed int64
    (8 bytes a message, not a Python int each)."""

    msgtype: str
    stamps: array[int] = field(default_factory=lambda: array("q"))
    raws: list[bytes] = field(default_factory=list)
    seqs: array[int] = field(default_factory=lambda: array("q"))
    column: Float32Column | None = None  # decoded as read: ``raws`` stays empty while it is set
    has_raws: bool = True  # False: a topic fed to an AssemblySink whose bytes were dropped
    types: list[str] = field(default_factory=list)  # the topic's types in the order they appear
    kinds: array[int] | None = None  # per message, its type's index in ``types``; None: one type

    def __post_init__(self) -> None:
        self.types = self.types or [self.msgtype]

    def type_of(self, msgtype: str) -> None:
        """Note the type of the message about to be added: a topic whose connections differ in type
        (a split bag where a command changed type) keeps each message's own (ends a column)."""
        if self.kinds is None:
            if msgtype == self.msgtype:
                return
            self.kinds = array("B", bytes(len(self.stamps)))
            if self.column is not None:
                self.raws, self.column = self.column.to_raws(), None
        if msgtype not in self.types:
            self.types.append(msgtype)
        self.kinds.append(self.types.index(msgtype))

    def message_types(self) -> list[str]:
        """The type of every message, in the topic's current order."""
        if self.kinds is None:
            return [self.msgtype] * len(self.stamps)
        return [self.types[k] for k in self.kinds]

    def add(self, stamp: int, data: bytes, seq: int, msgtype: str | None = None) -> None:
        """Append one message (decoded into the column when there is one and it fits)."""
        if msgtype is not None and (self.kinds is not None or msgtype != self.msgtype):
            self.type_of(msgtype)
        self.stamps.append(stamp)
        self.seqs.append(seq)
        if self.column is not None:
            if self.column.add(data):
                return
            self.raws = self.column.to_raws()  # the streaming ends: exact bytes of the rows so far
            self.column = None
        if self.has_raws:
            self.raws.append(data)

    def keep(self, index: list[int]) -> None:
        """Keep messages ``index`` (in that order)."""
        self.stamps = array("q", [self.stamps[i] for i in index])
        self.seqs = array("q", [self.seqs[i] for i in index])
        if self.kinds is not None:
            self.kinds = array("B", [self.kinds[i] for i in index])
        if self.column is not None:
            self.column.take(np.asarray(index, dtype=np.int64))
        elif self.has_raws:
            self.raws = [self.raws[i] for i in index]


@dataclass
class RawBag:
    """Everything read from one bag; ``corrupt`` = the corruption that ended the read, if any."""

    path: Path
    types: dict[str, str]
    topics: dict[str, TopicData]
    corrupt: CorruptBagError | None = None
    untrusted: str | None = None  # damage found that no scan could locate: no episode is trusted
    count: int = 0  # messages read so far (wanted or not): the next record position
    assembly: AssemblySink | None = None  # the assembler's rows when they were built while reading
    cut: int | None = None  # truncate(): messages stamped at or after it are dropped
    notes: list[str] = field(default_factory=list)  # for the bag's report (e.g. a QoS string mismatch)
    repeats: Repeats = field(default_factory=Repeats)  # messages sent twice, dropped (data.cuts.repeats)

    def append(self, wanted: set[str] | None, topic: str, msgtype: str, stamp: int, data: bytes) -> None:
        """Add one message when its topic is wanted."""
        self.count += 1
        if (wanted is not None and topic not in wanted) or self.repeats.seen(topic, msgtype, stamp, data):
            return
        tdata = self.topics.get(topic)
        if tdata is None:
            tdata = self.topics[topic] = TopicData(msgtype)
        tdata.add(stamp, data, self.count - 1, msgtype)

    def truncate(self, stamp: int) -> None:
        """Drop every message stamped at or after ``stamp`` (the corrupt tail)."""
        self.cut = stamp if self.cut is None else min(self.cut, stamp)
        self.assembly = None  # built over the whole bag: rebuilt from the storage (reader.observe)
        for tdata in self.topics.values():
            keep = [i for i, s in enumerate(tdata.stamps) if s < stamp]
            if len(keep) != len(tdata.stamps):
                tdata.keep(keep)

    def topic_types(self, topic: str) -> list[str]:
        """The types of ``topic`` in the order its messages show them (several in a split bag where
        the topic changed type)."""
        tdata = self.topics.get(topic)
        if tdata is not None:
            return list(tdata.types)
        return [self.types[topic]] if topic in self.types else []


Planner = Callable[[dict[str, str]], "StreamPlan | None"]  # topic types -> what to decode while reading
Chooser = Callable[[dict[str, str]], set[str]]  # topic types -> the topics to keep (no metadata.yaml)


def _unfinished_hint(err: Exception) -> str:
    """The way out when an mcap file has no end yet: a bag still being recorded, or one whose
    recorder was killed (rosbags: 'File end magic is invalid')."""
    if "end magic" not in str(err).lower():
        return ""
    return ("; the bag looks unfinished (still being recorded, or its recorder did not close it): "
            "--on-error skip_tail (ompn_train: --set data.on_error=skip_tail) keeps its whole episodes")


def collect_rosbags(bag: Path, wanted: set[str] | None, planner: Planner | None = None,
                    choose: Chooser | None = None) -> RawBag:
    """Read every message of the wanted topics with ``rosbags`` (the normal path).

    ``rosbags`` checks mcap chunk CRCs when the writer set them; a mismatch ends the read like
    any other storage error: the messages read before it are kept and ``corrupt`` names the file.
    ``planner``: given the bag's topic types, the topics to decode while reading (:class:`StreamPlan`).
    ``choose``: given the bag's topic types, the topics to keep when ``wanted`` is ``None`` (a bag
    without metadata.yaml: only the wanted topics' bytes are held, whatever else the bag records).
    Raises :class:`CorruptBagError` when the bag cannot even be opened.
    """
    raw = RawBag(bag, {}, {})
    read = 0
    reader = Reader(bag)
    try:
        reader.open()
    except Exception as err:  # rosbags raises many types on broken storage
        files = storage_files(bag) if bag.is_dir() else [bag]
        where = files[0] if len(files) == 1 else bag
        raise CorruptBagError(f"cannot open bag: {err}{_unfinished_hint(err)}", path=where) from err
    for c in reader.connections:
        raw.types.setdefault(c.topic, c.msgtype)  # a topic under several types: its first
    if wanted is None and choose is not None:
        wanted = choose(raw.types)
    conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
    try:
        register_bag_types(bag, conns)
    except BaseException:
        reader.close()
        raise
    for topic in {c.topic for c in conns}:
        raw.topics[topic] = TopicData(raw.types[topic])
    try:
        sink = _apply_plan(raw, planner(raw.types) if planner else None, _counts(conns))
    except BaseException:  # not a storage error: the reader is closed and the error goes up
        reader.close()
        raise
    try:
        if conns:
            fed = set(sink.spec.topics) if sink is not None else set()
            for conn, stamp, data in bag_messages(reader, conns, raw.notes, raw.repeats):
                topic, tdata = conn.topic, raw.topics[conn.topic]
                tdata.add(stamp, data, read, conn.msgtype)
                if topic in fed:
                    assert sink is not None
                    sink.add(topic, stamp, data, conn.msgtype)
                read += 1
    except Exception as err:  # any storage error ends the read; the caller decides what to keep
        raw.corrupt = CorruptBagError(f"read failed after {read} messages: {type(err).__name__} {err}",
                                      path=bag)
    finally:
        try:
            reader.close()
        except Exception:  # closing a broken storage must not hide the real error
            pass
    raw.count = read
    return raw


def register_bag_types(bag: Path, conns: list[Connection]) -> None:
    """Register the message types the bag defines for ``conns`` that the typestore lacks (rosbag2
    stores each topic's definition: sqlite3 ``message_definitions``, mcap schemas)."""
    for c in conns:
        if builtin(c.msgtype) or c.msgdef.format == MessageDefinitionFormat.NONE:
            continue
        fmt = "idl" if c.msgdef.format == MessageDefinitionFormat.IDL else "msg"
        try:
            register_definition(c.msgtype, fmt, c.msgdef.data)
        except TypeDefinitionError as err:
            raise UnknownTypeError(f"{err}; name its .msg folder with `types: DIR` in the reader spec",
                                   path=bag, topic=c.topic) from err


def bag_messages(reader: Reader, conns: list[Connection], notes: list[str],
                 repeats: Repeats) -> Iterator[tuple[Connection, int, bytes]]:
    """The messages of ``conns`` in record order, as every read of an opened bag takes them: with the
    storage files' own connections whose QoS string differs (:func:`storage_connections`),
    decompressed when undeclared zstd frames (:func:`_decompressed`), without repeats
    (:mod:`.repeats`).  ``notes`` gets one line per topic read despite a QoS mismatch."""
    unmatched = storage_connections(reader, conns)
    notes.extend(f"topic '{topic}': the QoS profiles or type hash in metadata.yaml differ from the "
                 "storage file's; its messages are read anyway (as ros2 bag play does)"
                 for topic in sorted({c.topic for c in unmatched}))
    return unrepeated(_decompressed(reader.messages(connections=conns + unmatched), notes), repeats)


def _decompressed(messages: Iterator[tuple[Connection, int, bytes]],
                  notes: list[str]) -> Iterator[tuple[Connection, int, bytes]]:
    """``messages``, decompressed when the first one is a zstd frame that no metadata.yaml declared
    (:mod:`.compressed`; a note is added)."""
    unzip: bool | None = None
    for conn, stamp, data in messages:
        if unzip is None:
            unzip = is_compressed(data)
            if unzip:
                notes.append(compressed_note)
        yield conn, stamp, (decompress(data) if unzip else data)


def storage_connections(reader: Reader, conns: list[Connection]) -> list[Connection]:
    """Connections of the storage files that none of ``conns`` (from metadata.yaml) matches although
    they carry a topic and type of ``conns``: ``rosbags`` pairs them on every field, QoS string and type
    hash included, and yields no message for them (rosbag2's own test bags, bags rewritten by
    ``ros2 bag convert``).  Passing them as well reads those messages.  Cost: O(connections²)."""
    storages = getattr(reader.storage, "storages", [])  # a bag directory: one reader per storage file
    wanted = {(c.topic, c.msgtype) for c in conns}
    out: list[Connection] = []
    for storage in storages:
        for sc in storage.connections:
            if (sc.topic, sc.msgtype) in wanted and not any(_same(c, sc) for c in conns):
                out.append(sc)
    return out


def _same(meta: Connection, stored: Connection) -> bool:
    """Whether ``rosbags`` pairs a metadata.yaml connection with a storage file's."""
    return (meta.topic == stored.topic and meta.msgtype == stored.msgtype and meta.ext == stored.ext
            and (not meta.digest or not stored.digest or meta.digest == stored.digest))


def _counts(conns: list[Connection]) -> dict[str, int]:
    """Messages per topic from the bag's index (0 when it does not say)."""
    out: dict[str, int] = {}
    for c in conns:
        out[c.topic] = out.get(c.topic, 0) + int(c.msgcount or 0)
    return out


def _apply_plan(raw: RawBag, plan: StreamPlan | None, counts: dict[str, int]) -> AssemblySink | None:
    """Set the column and the assembler sink of ``plan`` on the topics read (``None``: no sink)."""
    if plan is None:
        return None
    for topic, dim in ((plan.column, plan.dim), (plan.act_column, plan.act_dim)):
        if topic is not None and topic in raw.topics:
            raw.topics[topic].column = Float32Column(dim, counts.get(topic, 0))
    if plan.assemble is None or not set(plan.assemble.topics) <= set(raw.topics):
        return None
    for topic in plan.assemble.topics:
        raw.topics[topic].has_raws = topic in plan.keep_raw
    raw.assembly = AssemblySink(plan.assemble, counts.get(plan.assemble.step_topic, 0))
    return raw.assembly
