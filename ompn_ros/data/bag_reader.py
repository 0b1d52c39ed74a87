"""Read rosbag2 files (mcap or sqlite3) into Episodes.

Inputs: a storage file (``.mcap``/``.db3``), a bag directory (with ``metadata.yaml``), a directory
holding bag directories (searched recursively), a glob, or a sequence of those.  Bags are read in
sorted path order and their episodes concatenated.

Alignment rule
--------------
* The **observation topic is the step clock**: its messages, sorted by stamp, are the steps.
* A message on another per-step topic (action, subtask, joint states) **attaches to the latest
  observation stamped at or before it**, if it is at most ``tolerance`` seconds after that
  observation.  Messages attaching to no observation are counted as *unattached* per topic.
* An observation lacking a partner on a per-step topic is counted as *missing* for that topic, and
  a second partner for the same observation is counted as a *duplicate* (the first one is kept).
  Nothing is ever shifted to a neighbouring step.  With ``strict`` (our presets) a missing or
  duplicate partner raises :class:`AlignmentError`; otherwise a step without an action is dropped
  (observation included), a missing subtask becomes ``-1`` and a missing joint state ``NaN``, and
  everything is counted in the :class:`ReadReport`.
* In bags written by ``ompn_collect`` alignment is exact: partners follow their observation by
  ``k * TOPIC_OFFSET_NS``.  Live sims publish ``subtask_t``/``action_t`` one tick after
  ``observation_t`` (just before ``observation_{t+1}``; in policy mode after the policy's reply),
  so the default ``tolerance`` is a generous 5 s: the episode markers and the "latest observation
  at or before" rule do the alignment, the tolerance only rejects strays.
* Stamps are the bag's log stamps (``stamp: log``); ``stamp: header`` uses ``header.stamp`` of
  JointState topics instead.

Episodes
--------
Episode start/end markers (``DiagnosticArray`` on the episode topic, keys in ``layout.py``) delimit
the episodes when present; observations outside a start/end pair are not used (a recording started
or stopped mid-episode) and an unfinished episode is dropped and reported.  Without markers,
episodes are split where consecutive observations are more than ``time_gap`` seconds apart.

Within an episode the last observation without an action becomes row ``T`` (the final observation
of the step contract).  If every observation has an action (foreign bags), the last observation is
duplicated as row ``T`` (the paper's ``s_{T+1} = s_T`` variant) and the report notes it.  The sketch
is the sketch message of the episode (between its start marker and first observation, or, without
markers, the latest one before the first observation), else the start marker's ``sketch`` key.

Errors
------
``on_error='raise'`` raises the first :class:`BagError`.  ``on_error='skip_tail'`` keeps the
episodes completed before a corrupt tail (unreadable storage, undecodable or wrong-length
message; the data from the first bad message on is discarded) and reports what was dropped.  A
wrong message type or a missing required topic always raises.
"""

from __future__ import annotations

import glob as globmod
import itertools
import sqlite3
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ompn_ros import layout

from . import messages as m
from .bag_writer import resolve_topic
from .episode import Episode
from .errors import (
    AlignmentError,
    BagError,
    BagNotFoundError,
    CorruptBagError,
    MissingTopicError,
    ReaderSpecError,
    TopicTypeError,
    UnknownTypeError,
    VectorLengthError,
)

OnError = Literal["raise", "skip_tail"]
VECTOR_TYPES = (layout.FLOAT32_ARRAY, layout.JOINT_STATE)
ACTION_TYPES = (layout.INT32, layout.FLOAT32_ARRAY, layout.JOINT_STATE)
JOINT_FIELDS = ("position", "velocity", "effort")
STORAGE_SUFFIXES = (".mcap", ".db3")


# --- spec -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VectorSource:
    """Where a per-step vector comes from.

    Attributes:
        topic: topic name (relative names resolve in ``ReaderSpec.namespace``).
        type: ``Float32MultiArray``, ``JointState`` or (actions) ``Int32``; ``None`` = as in the bag.
        dim: expected vector size (checked), ``None`` = the size of the topic's first message.
        fields: JointState fields concatenated in this order (``position``/``velocity``/``effort``).
        joint_names: JointState joint order (by name); ``None`` = the message's own order.
    """

    topic: str
    type: str | None = layout.FLOAT32_ARRAY
    dim: int | None = None
    fields: tuple[str, ...] = ("position",)
    joint_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        bad = [f for f in self.fields if f not in JOINT_FIELDS]
        if bad or not self.fields:
            raise ReaderSpecError(f"topic '{self.topic}': JointState fields must be a non-empty subset "
                                  f"of {JOINT_FIELDS}, got {list(self.fields)}")
        if self.type is not None and self.type not in ACTION_TYPES:
            raise ReaderSpecError(f"topic '{self.topic}': unsupported type '{self.type}', "
                                  f"expected one of {ACTION_TYPES}")


@dataclass(frozen=True)
class ReaderSpec:
    """Which topics and types make up an episode, and how to align and split them.

    Attributes:
        observation, action: the per-step vectors (the action may come from the observation
            topic itself, e.g. ``JointState.velocity``: then every observation has its action).
        subtask, sketch, episode, joint_states: optional topics (``None`` = not used; absent from
            a bag = not used).  ``joint_states`` fills ``Episode.extras['joint_*']``.
        namespace: resolves relative topic names; a relative name absent under it falls back to
            the unique bag topic ending in ``/<name>``.
        time_gap: seconds between observations that split episodes when there are no markers.
        tolerance: seconds a partner may follow its observation (see the alignment rule).
        strict: raise :class:`AlignmentError` on missing/duplicate partners instead of counting.
        stamp: ``'log'`` (bag stamps) or ``'header'`` (``header.stamp`` of JointState topics;
            meant for foreign bags whose per-step topics are all JointState on one clock).
        task: task name for episodes without a start marker.
    """

    observation: VectorSource = VectorSource(layout.OBSERVATION)
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
    task: str = ""

    def __post_init__(self) -> None:
        if self.observation.type not in VECTOR_TYPES:
            raise ReaderSpecError(f"observation type must be one of {VECTOR_TYPES}, "
                                  f"got '{self.observation.type}'")
        if self.time_gap <= 0 or self.tolerance < 0:
            raise ReaderSpecError(f"time_gap must be > 0 and tolerance >= 0 (got {self.time_gap}, "
                                  f"{self.tolerance})")
        if self.stamp not in ("log", "header"):
            raise ReaderSpecError(f"stamp must be 'log' or 'header', got '{self.stamp}'")

    @classmethod
    def for_domain(cls, domain: str | layout.DomainLayout) -> ReaderSpec:
        """The preset for our own sims' bags (same as ``config/reader_<domain>.yaml``)."""
        dom = layout.DOMAINS[domain] if isinstance(domain, str) else domain
        return cls(
            observation=VectorSource(layout.OBSERVATION, layout.FLOAT32_ARRAY, dom.obs_dim),
            action=VectorSource(layout.ACTION, dom.action_msg,
                                None if dom.action_type == "discrete" else dom.action_dim),
            joint_states=layout.JOINT_STATES if dom.has_joint_states else None,
            strict=True,
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
        kwargs = dict(data)
        for key in ("observation", "action"):
            if key in kwargs:
                kwargs[key] = _vector_source(key, kwargs[key])
        try:
            return cls(**kwargs)
        except TypeError as err:
            raise ReaderSpecError(f"bad reader spec: {err}") from err

    @classmethod
    def from_yaml(cls, path: str | Path) -> ReaderSpec:
        """Load a spec from a YAML file (see ``config/reader_*.yaml``)."""
        import yaml

        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
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
            src = out[key]
            src["fields"] = list(src["fields"])
            src["joint_names"] = None if src["joint_names"] is None else list(src["joint_names"])
        return out


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
    try:
        return VectorSource(**value)
    except TypeError as err:
        raise ReaderSpecError(f"bad '{key}' entry: {err}") from err


# --- report ---------------------------------------------------------------------------------------
@dataclass
class BagReport:
    """What was read from one bag, and what was not used."""

    path: str
    episodes: int = 0
    steps: int = 0
    split: str = ""  # 'markers' | 'time_gap'
    messages: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)  # steps lacking a partner, per topic
    duplicates: dict[str, int] = field(default_factory=dict)  # extra partners for one step
    unattached: dict[str, int] = field(default_factory=dict)  # messages attached to no step
    dropped_steps: int = 0
    dropped_episodes: int = 0
    final_duplicated: int = 0  # episodes whose row T duplicates the last observation
    error: str | None = None  # the corruption that ended the read (skip_tail)
    notes: list[str] = field(default_factory=list)

    def _add(self, table: dict[str, int], topic: str, n: int) -> None:
        if n:
            table[topic] = table.get(topic, 0) + int(n)


@dataclass
class ReadReport:
    """Per-bag reports of one :func:`read_episodes` call."""

    bags: list[BagReport] = field(default_factory=list)

    @property
    def episodes(self) -> int:
        return sum(b.episodes for b in self.bags)

    @property
    def steps(self) -> int:
        return sum(b.steps for b in self.bags)

    def total(self, name: str) -> dict[str, int]:
        """Sum the per-topic table ``name`` ('missing', 'duplicates', 'unattached', 'messages')."""
        out: dict[str, int] = {}
        for bag in self.bags:
            for topic, n in getattr(bag, name).items():
                out[topic] = out.get(topic, 0) + n
        return out

    @property
    def errors(self) -> list[str]:
        return [b.error for b in self.bags if b.error]

    def summary(self) -> str:
        """Human-readable multi-line summary."""
        lines = [f"{len(self.bags)} bag(s), {self.episodes} episode(s), {self.steps} step(s)"]
        for b in self.bags:
            line = f"  {b.path}: {b.episodes} episodes, {b.steps} steps ({b.split})"
            for name in ("missing", "duplicates", "unattached"):
                table = getattr(b, name)
                if table:
                    line += f"; {name} {table}"
            if b.dropped_steps:
                line += f"; dropped steps {b.dropped_steps}"
            if b.dropped_episodes:
                line += f"; dropped episodes {b.dropped_episodes}"
            if b.final_duplicated:
                line += f"; last observation duplicated as row T in {b.final_duplicated} episodes"
            lines.append(line)
            if b.error:
                lines.append(f"    error: {b.error}")
            lines.extend(f"    note: {n}" for n in b.notes)
        return "\n".join(lines)


@dataclass
class ReadResult:
    """Episodes read and the report of what was (not) used."""

    episodes: list[Episode]
    report: ReadReport


# --- path resolution ------------------------------------------------------------------------------
def resolve_bag_paths(paths: str | Path | Sequence[str | Path]) -> list[Path]:
    """Expand files, bag directories, directories of bags and globs into a sorted list of bags."""
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    out: list[Path] = []
    for item in items:
        text = str(item)
        if any(ch in text for ch in "*?[") and not Path(text).exists():
            matches = sorted(globmod.glob(text, recursive=True))
            if not matches:
                raise BagNotFoundError("glob matched nothing", path=text)
            for match in matches:
                out.extend(_expand(Path(match)))
        else:
            found = _expand(Path(text))
            if not found:
                raise BagNotFoundError("no rosbag2 bag (metadata.yaml, .mcap or .db3) found", path=text)
            out.extend(found)
    unique: list[Path] = []
    for p in out:
        if p not in unique:
            unique.append(p)
    return unique


def _expand(path: Path) -> list[Path]:
    if not path.exists():
        raise BagNotFoundError("no such file or directory", path=path)
    if path.is_file():
        if path.suffix in STORAGE_SUFFIXES:
            return [path]
        if path.name == "metadata.yaml":
            return [path.parent]
        raise BagNotFoundError(f"not a bag storage file (expected {STORAGE_SUFFIXES})", path=path)
    if (path / "metadata.yaml").is_file():
        return [path]
    found: list[Path] = []
    for child in sorted(path.iterdir()):
        if child.name.startswith("."):
            continue  # temp parts of ompn_collect, hidden directories
        if child.is_dir():
            found.extend(_expand(child))
        elif child.suffix in STORAGE_SUFFIXES:
            found.append(child)
    return found


def storage_files(bag: Path) -> list[Path]:
    """The storage files of a bag (the file itself, or the ``.mcap``/``.db3`` files of the dir)."""
    if bag.is_file():
        return [bag]
    return sorted(p for p in bag.iterdir() if p.suffix in STORAGE_SUFFIXES)


# --- raw collection -------------------------------------------------------------------------------
@dataclass
class _TopicData:
    msgtype: str
    stamps: list[int] = field(default_factory=list)
    raws: list[bytes] = field(default_factory=list)


@dataclass
class _RawBag:
    path: Path
    types: dict[str, str]
    topics: dict[str, _TopicData]
    corrupt: CorruptBagError | None = None


def _collect_rosbags(bag: Path, wanted: set[str] | None) -> _RawBag:
    """Read every message of the wanted topics with ``rosbags`` (the normal path)."""
    from rosbags.rosbag2 import Reader

    raw = _RawBag(bag, {}, {})
    read = 0
    reader = Reader(bag)
    try:
        reader.open()
    except Exception as err:
        files = storage_files(bag) if bag.is_dir() else [bag]
        where = files[0] if len(files) == 1 else bag
        raise CorruptBagError(f"cannot open bag: {err}", path=where) from err
    try:
        raw.types = {c.topic: c.msgtype for c in reader.connections}
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for topic in {c.topic for c in conns}:
            raw.topics[topic] = _TopicData(raw.types[topic])
        if conns:
            by_id = {c.id: raw.topics[c.topic] for c in conns}
            for conn, stamp, data in reader.messages(connections=conns):
                tdata = by_id[conn.id]
                tdata.stamps.append(stamp)
                tdata.raws.append(data)
                read += 1
    except Exception as err:
        raw.corrupt = CorruptBagError(f"read failed after {read} messages: {type(err).__name__} {err}",
                                      path=bag)
    finally:
        try:
            reader.close()
        except Exception:  # closing a broken storage must not hide the real error
            pass
    return raw


def _salvage(bag: Path, wanted: set[str] | None, first_error: CorruptBagError) -> _RawBag:
    """Read what precedes the corruption, record by record, without the storage's index."""
    raw = _RawBag(bag, {}, {}, corrupt=first_error)
    for file in storage_files(bag):
        try:
            if file.suffix == ".mcap":
                ok = _salvage_mcap(file, wanted, raw)
            else:
                ok = _salvage_sqlite(file, wanted, raw)
        except Exception as err:
            raw.corrupt = CorruptBagError(f"unreadable storage: {err}", path=file)
            ok = False
        if not ok:
            break  # later files are after the corruption: not a tail we can trust
    return raw


def _append(raw: _RawBag, wanted: set[str] | None, topic: str, msgtype: str, stamp: int,
            data: bytes) -> None:
    if wanted is not None and topic not in wanted:
        return
    tdata = raw.topics.get(topic)
    if tdata is None:
        tdata = raw.topics[topic] = _TopicData(msgtype)
    tdata.stamps.append(stamp)
    tdata.raws.append(data)


def _salvage_mcap(file: Path, wanted: set[str] | None, raw: _RawBag) -> bool:
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    n = 0
    with open(file, "rb") as fh:
        try:
            for rec in StreamReader(fh, record_size_limit=1 << 30).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
                    raw.types.setdefault(rec.topic, schemas.get(rec.schema_id, ""))
                elif isinstance(rec, Message):
                    topic, msgtype = channels[rec.channel_id]
                    _append(raw, wanted, topic, msgtype, rec.log_time, rec.data)
                    n += 1
        except Exception as err:
            text = f"mcap stream broken after {n} messages: {type(err).__name__} {err}".rstrip()
            raw.corrupt = CorruptBagError(text, path=file)
            return False
    return True


def _salvage_sqlite(file: Path, wanted: set[str] | None, raw: _RawBag) -> bool:
    con = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
    n = 0
    try:
        topics = {tid: (name, typ) for tid, name, typ in con.execute("SELECT id, name, type FROM topics")}
        for name, typ in topics.values():
            raw.types.setdefault(name, typ)
        try:
            for tid, stamp, data in con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id"):
                name, typ = topics[tid]
                _append(raw, wanted, name, typ, int(stamp), bytes(data))
                n += 1
        except sqlite3.DatabaseError as err:
            text = f"sqlite scan broken after {n} messages: {type(err).__name__} {err}"
            raw.corrupt = CorruptBagError(text, path=file)
            return False
    finally:
        con.close()
    return True


def _truncate(raw: _RawBag, stamp: int) -> None:
    """Drop every message stamped at or after ``stamp`` (the corrupt tail)."""
    for tdata in raw.topics.values():
        keep = [i for i, s in enumerate(tdata.stamps) if s < stamp]
        if len(keep) != len(tdata.stamps):
            tdata.stamps = [tdata.stamps[i] for i in keep]
            tdata.raws = [tdata.raws[i] for i in keep]


# --- per-bag assembly -----------------------------------------------------------------------------
class _BagContext:
    """Resolved topics of one bag and helpers naming the file in errors."""

    def __init__(self, raw: _RawBag, spec: ReaderSpec, report: BagReport) -> None:
        self.raw = raw
        self.spec = spec
        self.report = report
        self.path = str(raw.path)

    def resolve(self, name: str | None, required: bool) -> str | None:
        if name is None:
            return None
        topic = resolve_topic(name, self.spec.namespace)
        if topic in self.raw.types:
            return topic
        if not name.startswith("/"):
            candidates = [t for t in self.raw.types if t.endswith("/" + name)]
            if len(candidates) == 1:
                self.report.notes.append(f"topic '{name}' resolved to '{candidates[0]}'")
                return candidates[0]
        if required:
            raise MissingTopicError(f"required topic not in bag (bag topics: {sorted(self.raw.types)})",
                                    path=self.path, topic=topic)
        return None

    def data(self, topic: str) -> tuple[np.ndarray, list[bytes]]:
        """Stamps (int64, sorted) and raw messages of ``topic``."""
        tdata = self.raw.topics.get(topic)
        if tdata is None:
            return np.zeros(0, dtype=np.int64), []
        stamps = np.asarray(tdata.stamps, dtype=np.int64)
        if stamps.size > 1 and np.any(np.diff(stamps) < 0):
            order = np.argsort(stamps, kind="stable")
            stamps = stamps[order]
            tdata.raws = [tdata.raws[i] for i in order]
            tdata.stamps = stamps.tolist()
        return stamps, tdata.raws

    def check_type(self, topic: str, allowed: Sequence[str], expected: str | None) -> str:
        msgtype = self.raw.types[topic]
        if msgtype not in m.typestore().types:
            raise UnknownTypeError(f"message type '{msgtype}' is not in the ROS 2 Jazzy typestore",
                                   path=self.path, topic=topic, index=0)
        if expected is not None and msgtype != expected:
            raise TopicTypeError(f"carries '{msgtype}', the reader spec expects '{expected}'",
                                 path=self.path, topic=topic, index=0)
        if msgtype not in allowed:
            raise TopicTypeError(f"carries '{msgtype}', expected one of {list(allowed)}",
                                 path=self.path, topic=topic, index=0)
        return msgtype


def _vectors(ctx: _BagContext, topic: str, msgtype: str, src: VectorSource,
             stamps: np.ndarray, raws: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Decode a vector topic: values ``[N, D]`` and the stamps to align with."""
    if msgtype == layout.FLOAT32_ARRAY:
        return m.stack_float32_arrays(raws, expected_dim=src.dim, path=ctx.path, topic=topic,
                                      stamps=stamps), stamps
    return _joint_vectors(ctx, topic, src, stamps, raws)


@dataclass
class _JointBlock:
    """Decoded JointState messages of one topic: header stamps, names and NaN-padded field arrays."""

    header: np.ndarray  # int64 [N]
    names: list[tuple[str, ...]]  # per message
    arrays: dict[str, np.ndarray]  # field -> float64 [N, W] (W = width of the first message)
    widths: dict[str, np.ndarray]  # field -> int [N] actual width per message

    @property
    def uniform_names(self) -> bool:
        return all(n == self.names[0] for n in self.names)


def _decode_joint_states(ctx: _BagContext, topic: str, stamps: np.ndarray, raws: list[bytes]) -> _JointBlock:
    """Bulk fast path when all messages share one layout, else message by message."""
    fast = m.stack_joint_states(raws)
    if fast is not None:
        shared_names, shared_header, bulk = fast
        n = len(raws)
        return _JointBlock(shared_header, [tuple(shared_names)] * n, bulk,
                           {f: np.full(n, a.shape[1]) for f, a in bulk.items()})
    header = np.zeros(len(raws), dtype=np.int64)
    names_list: list[tuple[str, ...]] = []
    rows: dict[str, list[np.ndarray]] = {f: [] for f in JOINT_FIELDS}
    for i, data in enumerate(raws):
        try:
            names, header[i], values = m.parse_joint_state(data)
        except Exception as err:
            raise CorruptBagError(f"cannot decode JointState: {err}", path=ctx.path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        names_list.append(tuple(names))
        for f in JOINT_FIELDS:
            rows[f].append(values[f])
    arrays: dict[str, np.ndarray] = {}
    widths: dict[str, np.ndarray] = {}
    for f in JOINT_FIELDS:
        w = len(rows[f][0]) if rows[f] else 0
        arr = np.full((len(raws), w), np.nan)
        widths[f] = np.asarray([len(r) for r in rows[f]], dtype=np.int64)
        for i, r in enumerate(rows[f]):
            if len(r) == w:
                arr[i] = r
        arrays[f] = arr
    return _JointBlock(header, names_list, arrays, widths)


def _joint_vectors(ctx: _BagContext, topic: str, src: VectorSource, stamps: np.ndarray,
                   raws: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Observation/action vectors from JointState fields (optionally reordered by joint name)."""
    block = _decode_joint_states(ctx, topic, stamps, raws)
    n = len(raws)
    parts = []
    for name in src.fields:
        arr, widths = block.arrays[name], block.widths[name]
        if src.joint_names is None:
            bad = np.flatnonzero(widths != arr.shape[1])
            if bad.size:
                i = int(bad[0])
                raise VectorLengthError(f"JointState.{name} has {widths[i]} values, the topic's first "
                                        f"message {arr.shape[1]}", path=ctx.path, topic=topic, index=i,
                                        stamp=int(stamps[i]))
            parts.append(arr)
            continue
        out = np.empty((n, len(src.joint_names)))
        cache: dict[tuple[str, ...], np.ndarray] = {}
        groups = [range(n)] if block.uniform_names else [[i] for i in range(n)]
        for rows in groups:
            i = rows[0]
            key = block.names[i]
            order = cache.get(key)
            if order is None:
                index = {nm: k for k, nm in enumerate(key)}
                absent = [nm for nm in src.joint_names if nm not in index]
                if absent:
                    raise VectorLengthError(f"JointState lacks joints {absent}", path=ctx.path,
                                            topic=topic, index=i, stamp=int(stamps[i]))
                order = cache[key] = np.asarray([index[nm] for nm in src.joint_names])
            sel = np.asarray(rows)
            bad = sel[widths[sel] != len(key)]
            if bad.size:
                j = int(bad[0])
                raise VectorLengthError(f"JointState.{name} has {widths[j]} values for {len(key)} joint "
                                        "names", path=ctx.path, topic=topic, index=j, stamp=int(stamps[j]))
            out[sel] = arr[sel][:, order]
        parts.append(out)
    values = np.concatenate(parts, axis=1).astype(np.float32)
    if src.dim is not None and values.shape[1] != src.dim:
        raise VectorLengthError(f"vector has {values.shape[1]} elements, expected {src.dim}", path=ctx.path,
                                topic=topic, index=0, stamp=int(stamps[0]) if n else None)
    return values, (block.header if ctx.spec.stamp == "header" else stamps)


@dataclass
class _Partners:
    """Per-observation index of the first partner message (-1 = none) on one topic."""

    topic: str
    first: np.ndarray  # [N_obs] message index or -1
    count: np.ndarray  # [N_obs] number of partners


def _attach(ctx: _BagContext, topic: str, obs_stamps: np.ndarray, stamps: np.ndarray) -> _Partners:
    n_obs = len(obs_stamps)
    tol = round(ctx.spec.tolerance * 1e9)
    idx = np.searchsorted(obs_stamps, stamps, side="right") - 1
    ok = idx >= 0
    ok[ok] = (stamps[ok] - obs_stamps[idx[ok]]) <= tol
    ctx.report._add(ctx.report.unattached, topic, int((~ok).sum()))
    msg_ids = np.flatnonzero(ok)
    count = np.bincount(idx[ok], minlength=n_obs)
    first = np.full(n_obs, -1, dtype=np.int64)
    uniq, pos = np.unique(idx[ok], return_index=True)
    first[uniq] = msg_ids[pos]
    dup_steps = np.flatnonzero(count > 1)
    if dup_steps.size:
        ctx.report._add(ctx.report.duplicates, topic, int((count[dup_steps] - 1).sum()))
        if ctx.spec.strict:
            second = msg_ids[np.flatnonzero(idx[ok] == dup_steps[0])[1]]
            raise AlignmentError(f"second partner for observation #{dup_steps[0]} (duplicate)",
                                 path=ctx.path, topic=topic, index=int(second),
                                 stamp=int(stamps[second]))
    return _Partners(topic, first, count)


@dataclass
class _Window:
    first_obs: int
    stop_obs: int  # exclusive
    start_stamp: int | None = None
    start: dict[str, str] = field(default_factory=dict)
    end: dict[str, str] = field(default_factory=dict)
    end_index: int = -1


def _windows_from_markers(ctx: _BagContext, topic: str, obs_stamps: np.ndarray) -> list[_Window] | None:
    stamps, raws = ctx.data(topic)
    markers = []
    for i, data in enumerate(raws):
        try:
            parsed = m.parse_marker(data)
        except Exception as err:
            raise CorruptBagError(f"cannot decode episode marker: {err}", path=ctx.path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        if parsed is not None:
            markers.append((int(stamps[i]), parsed[0], parsed[1], i))
    if not markers:
        return None
    windows: list[_Window] = []
    open_start: tuple[int, dict[str, str]] | None = None
    for stamp, kind, values, i in markers:
        if kind == layout.EPISODE_START:
            if open_start is not None:
                ctx.report.dropped_episodes += 1
                ctx.report.notes.append(f"episode started at {open_start[0]} ns has no end marker")
            open_start = (stamp, values)
        elif kind == layout.EPISODE_END:
            if open_start is None:
                ctx.report.notes.append(f"end marker #{i} without a start marker (recording began "
                                        "mid-episode); its observations are not used")
                continue
            a = int(np.searchsorted(obs_stamps, open_start[0], side="left"))
            b = int(np.searchsorted(obs_stamps, stamp, side="right"))
            windows.append(_Window(a, b, open_start[0], open_start[1], values, i))
            open_start = None
    if open_start is not None:
        ctx.report.dropped_episodes += 1
        ctx.report.notes.append(f"last episode (started at {open_start[0]} ns) has no end marker "
                                "(recording stopped or corrupt tail); dropped")
    return windows


def _windows_from_gaps(ctx: _BagContext, obs_stamps: np.ndarray) -> list[_Window]:
    if obs_stamps.size == 0:
        return []
    gap = round(ctx.spec.time_gap * 1e9)
    cuts = np.flatnonzero(np.diff(obs_stamps) > gap) + 1
    bounds = np.concatenate([[0], cuts, [obs_stamps.size]])
    return [_Window(int(a), int(b)) for a, b in itertools.pairwise(bounds)]


def _bag_episodes(raw: _RawBag, spec: ReaderSpec, report: BagReport) -> list[Episode]:
    """Assemble the episodes of one collected bag (see the module docstring for the rules)."""
    ctx = _BagContext(raw, spec, report)
    obs_topic = ctx.resolve(spec.observation.topic, True)
    act_topic = ctx.resolve(spec.action.topic, True)
    assert obs_topic is not None and act_topic is not None
    obs_type = ctx.check_type(obs_topic, VECTOR_TYPES, spec.observation.type)
    act_type = ctx.check_type(act_topic, ACTION_TYPES, spec.action.type)
    sub_topic = ctx.resolve(spec.subtask, False)
    sketch_topic = ctx.resolve(spec.sketch, False)
    ep_topic = ctx.resolve(spec.episode, False)
    js_topic = ctx.resolve(spec.joint_states, False)
    if sub_topic:
        ctx.check_type(sub_topic, (layout.INT32,), layout.INT32)
    if sketch_topic:
        ctx.check_type(sketch_topic, (layout.INT32_ARRAY,), layout.INT32_ARRAY)
    if ep_topic:
        ctx.check_type(ep_topic, (layout.DIAGNOSTIC_ARRAY,), layout.DIAGNOSTIC_ARRAY)
    if js_topic:
        ctx.check_type(js_topic, (layout.JOINT_STATE,), layout.JOINT_STATE)
    for topic in {t for t in (obs_topic, act_topic, sub_topic, sketch_topic, ep_topic, js_topic) if t}:
        report.messages[topic] = len(raw.topics[topic].stamps) if topic in raw.topics else 0

    obs_log, obs_raws = ctx.data(obs_topic)
    obs, obs_stamps = _vectors(ctx, obs_topic, obs_type, spec.observation, obs_log, obs_raws)
    obs_order = None  # header stamps may order the steps differently from the bag
    if obs_stamps is not obs_log and np.any(np.diff(obs_stamps) < 0):
        obs_order = np.argsort(obs_stamps, kind="stable")
        obs, obs_stamps = obs[obs_order], obs_stamps[obs_order]

    # actions: same topic as observations (foreign JointState bags) or a partner topic
    if act_topic == obs_topic:
        act_src_stamps, act_raws = obs_log, obs_raws
        act_first = np.arange(len(obs_stamps))
    else:
        act_src_stamps, act_raws = ctx.data(act_topic)
        act_first = None
    if act_type == layout.INT32:
        act_values: np.ndarray = m.stack_int32(act_raws, path=ctx.path, topic=act_topic,
                                               stamps=act_src_stamps)
        act_stamps = act_src_stamps
    else:
        act_values, act_stamps = _vectors(ctx, act_topic, act_type, spec.action, act_src_stamps, act_raws)
    if act_first is None:
        act_first = _attach(ctx, act_topic, obs_stamps, act_stamps).first
    elif obs_order is not None:
        act_values = act_values[obs_order]

    sub_first = sub_values = None
    if sub_topic:
        sub_stamps, sub_raws = ctx.data(sub_topic)
        sub_values = m.stack_int32(sub_raws, path=ctx.path, topic=sub_topic, stamps=sub_stamps)
        sub_first = _attach(ctx, sub_topic, obs_stamps, sub_stamps).first

    js_first = js_block = None
    if js_topic:
        js_log, js_raws = ctx.data(js_topic)
        js_block = _decode_joint_states(ctx, js_topic, js_log, js_raws)
        js_stamps = js_block.header if spec.stamp == "header" else js_log
        js_first = _attach(ctx, js_topic, obs_stamps, js_stamps).first

    sketches: list[tuple[int, np.ndarray]] = []
    if sketch_topic:
        sk_stamps, sk_raws = ctx.data(sketch_topic)
        sketches = [(int(s), m.parse_int32_array(r)) for s, r in zip(sk_stamps, sk_raws)]

    windows = _windows_from_markers(ctx, ep_topic, obs_stamps) if ep_topic else None
    if windows is None:
        report.split = "time_gap"
        windows = _windows_from_gaps(ctx, obs_stamps)
        if raw.corrupt is not None and windows:
            windows.pop()
            report.dropped_episodes += 1
            report.notes.append("last time-gap episode dropped: it precedes the corruption")
    else:
        report.split = "markers"
    used = sum(w.stop_obs - w.first_obs for w in windows)
    report._add(report.unattached, obs_topic, len(obs_stamps) - used)

    episodes: list[Episode] = []
    prev_stop_stamp = -1
    for w in windows:
        a, b = w.first_obs, w.stop_obs
        if b - a == 0:
            report.dropped_episodes += 1
            report.notes.append(f"episode at {w.start_stamp} ns has no observations; dropped")
            continue
        has_act = act_first[a:b] >= 0
        if has_act[-1]:
            steps = np.arange(a, b)
            report.final_duplicated += 1
        else:
            steps = np.arange(a, b - 1)
        final = b - 1
        lacking = steps[act_first[steps] < 0]
        if lacking.size:
            report._add(report.missing, act_topic, lacking.size)
            if spec.strict:
                raise AlignmentError(f"observation #{lacking[0]} has no action partner within "
                                     f"{spec.tolerance} s", path=ctx.path, topic=obs_topic,
                                     index=int(lacking[0]), stamp=int(obs_stamps[lacking[0]]))
            report.dropped_steps += int(lacking.size)
            steps = steps[act_first[steps] >= 0]
        if steps.size == 0:
            report.dropped_episodes += 1
            report.notes.append(f"episode of observations #{a}..#{b - 1} has no step with an action; dropped")
            continue
        rows = np.concatenate([steps, [final]])
        actions = act_values[act_first[steps]]
        subtask = None
        if sub_first is not None and sub_values is not None:
            sidx = sub_first[steps]
            n_missing = int((sidx < 0).sum())
            if n_missing:
                report._add(report.missing, sub_topic or "", n_missing)
                if spec.strict:
                    bad = int(steps[np.flatnonzero(sidx < 0)[0]])
                    raise AlignmentError(f"observation #{bad} has no subtask partner", path=ctx.path,
                                         topic=obs_topic, index=bad, stamp=int(obs_stamps[bad]))
            subtask = np.where(sidx >= 0, sub_values[np.maximum(sidx, 0)], -1).astype(np.int64)
        extras: dict[str, Any] = {}
        if js_first is not None and js_block is not None:
            extras = _joint_extras(ctx, js_topic or "", js_first, js_block, steps, final)
        sketch = _episode_sketch(sketches, w, int(obs_stamps[a]), prev_stop_stamp)
        prev_stop_stamp = int(obs_stamps[final])
        task = w.start.get(layout.KEY_TASK, spec.task)
        seed = _int_or(w.start.get(layout.KEY_SEED), -1)
        success = w.end.get(layout.KEY_SUCCESS, "true").lower() == "true"
        if w.end and _int_or(w.end.get(layout.KEY_STEPS), len(steps)) != len(steps):
            msg = (f"end marker says {w.end.get(layout.KEY_STEPS)} steps, the bag holds {len(steps)} "
                   f"for episode '{task}' seed {seed}")
            if spec.strict:
                raise AlignmentError(msg, path=ctx.path, topic=ep_topic, index=w.end_index)
            report.notes.append(msg)
        episodes.append(Episode(
            observations=obs[rows],
            actions=np.asarray(actions, dtype=np.int64 if act_type == layout.INT32 else np.float32),
            subtask=subtask, sketch=sketch, task=task, seed=seed, success=success, extras=extras,
        ))
        report.steps += len(steps)
    if report.final_duplicated:
        report.notes.append(f"every observation had an action in {report.final_duplicated} episode(s): "
                            "the last observation was duplicated as row T (s_{T+1} = s_T)")
    report.episodes = len(episodes)
    return episodes


def _int_or(text: str | None, default: int) -> int:
    try:
        return int(text) if text is not None else default
    except ValueError:
        return default


def _episode_sketch(sketches: list[tuple[int, np.ndarray]], w: _Window, first_obs_stamp: int,
                    prev_stop_stamp: int) -> np.ndarray | None:
    lower = w.start_stamp if w.start_stamp is not None else prev_stop_stamp + 1
    chosen = None
    for stamp, values in sketches:
        if lower <= stamp <= first_obs_stamp:
            chosen = values
    if chosen is None and w.start.get(layout.KEY_SKETCH):
        chosen = m.parse_sketch_value(w.start[layout.KEY_SKETCH])
    return chosen


def _joint_extras(ctx: _BagContext, topic: str, first: np.ndarray, block: _JointBlock, steps: np.ndarray,
                  final: int) -> dict[str, Any]:
    """``joint_<field>`` arrays aligned with the episode rows (NaN where a step has no joint state);
    ``T + 1`` rows when the final observation has a joint state, else ``T``."""
    idx = first[steps]
    lacking = int((idx < 0).sum())
    if lacking:
        ctx.report._add(ctx.report.missing, topic, lacking)
    rows = np.concatenate([idx, [first[final]]]) if first[final] >= 0 else idx
    present = rows[rows >= 0]
    if present.size == 0:
        return {}
    extras: dict[str, Any] = {"joint_names": list(block.names[int(present[0])])}
    for name in JOINT_FIELDS:
        arr = block.arrays[name]
        if arr.shape[1] == 0:
            continue
        out = np.full((len(rows), arr.shape[1]), np.nan)
        out[rows >= 0] = arr[present]
        extras[f"joint_{name}"] = out
    return extras


# --- public entry point ---------------------------------------------------------------------------
def _wanted_topics(spec: ReaderSpec, types: dict[str, str]) -> set[str]:
    wanted = set()
    for name in (spec.observation.topic, spec.action.topic, spec.subtask, spec.sketch, spec.episode,
                 spec.joint_states):
        if name is None:
            continue
        topic = resolve_topic(name, spec.namespace)
        wanted.add(topic)
        if not name.startswith("/"):
            wanted.update(t for t in types if t.endswith("/" + name))
    return wanted


def _topic_types(bag: Path) -> dict[str, str] | None:
    """Topic -> type from the bag's metadata without reading messages (None if unreadable)."""
    meta = bag / "metadata.yaml" if bag.is_dir() else None
    if meta is None or not meta.is_file():
        return None
    import yaml

    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: t["topic_metadata"]["type"]
                for t in info["topics_with_message_count"]}
    except Exception:
        return None


def read_bag(bag: Path, spec: ReaderSpec, on_error: OnError, report: BagReport) -> list[Episode]:
    """Read one bag (see :func:`read_episodes`)."""
    types = _topic_types(bag)
    wanted = _wanted_topics(spec, types) if types is not None else None
    try:
        raw = _collect_rosbags(bag, wanted)
    except CorruptBagError as err:
        if on_error == "raise":
            raise
        raw = _salvage(bag, wanted, err)
    if raw.corrupt is not None:
        if on_error == "raise":
            raise raw.corrupt
        report.error = str(raw.corrupt)
    for _ in range(1000):
        try:
            return _bag_episodes(raw, spec, report)
        except (TopicTypeError, MissingTopicError, UnknownTypeError):
            raise
        except BagError as err:
            if on_error == "raise" or err.stamp is None:
                raise
            # a bad message: everything from it on is the corrupt tail
            _truncate(raw, err.stamp)
            raw.corrupt = CorruptBagError(str(err), path=bag, topic=err.topic, index=err.index)
            fresh = BagReport(report.path, error=str(err))
            report.__dict__.update(fresh.__dict__)
    raise CorruptBagError("could not isolate the corrupt tail", path=bag)


def read_episodes(
    paths: str | Path | Sequence[str | Path],
    *,
    spec: ReaderSpec | None = None,
    on_error: OnError = "raise",
) -> ReadResult:
    """Read the episodes of one or more bags.

    Args:
        paths: a storage file, a bag directory, a directory of bags, a glob, or a sequence of them.
        spec: topics/types/alignment; ``None`` = defaults (our topic names, types as in the bag).
        on_error: ``'raise'`` or ``'skip_tail'`` (keep episodes before a corrupt tail, report it).

    Returns:
        ``ReadResult(episodes, report)``.
    """
    if on_error not in ("raise", "skip_tail"):
        raise ValueError(f"on_error must be 'raise' or 'skip_tail', got '{on_error}'")
    spec = spec or ReaderSpec()
    report = ReadReport()
    episodes: list[Episode] = []
    for bag in resolve_bag_paths(paths):
        bag_report = BagReport(str(bag))
        report.bags.append(bag_report)
        episodes.extend(read_bag(bag, spec, on_error, bag_report))
    return ReadResult(episodes, report)


def iter_raw_messages(bag: str | Path) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, stamp, raw)`` of every message (rosbags order); the baseline of the benchmark."""
    from rosbags.rosbag2 import Reader

    with Reader(Path(bag)) as reader:
        for conn, stamp, data in reader.messages():
            yield conn.topic, stamp, data


__all__ = [
    "BagReport",
    "ReadReport",
    "ReadResult",
    "ReaderSpec",
    "VectorSource",
    "iter_raw_messages",
    "read_bag",
    "read_episodes",
    "resolve_bag_paths",
]
