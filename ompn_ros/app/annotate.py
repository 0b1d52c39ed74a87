"""Annotated bags: a copy of a recording with ``ompn_node``'s outputs added at the observation stamps.

:func:`annotate_bag` copies every message of a rosbag2 (mcap or sqlite3; topic names, types,
message definitions, QoS, log stamps and CDR bytes kept exactly) into a new rosbag2 (metadata v9,
mcap by default, ``ros_distro: jazzy`` as the recorder writes it) and adds, for every replayed step
of every episode, what the live node would have published while that recording played, each topic
with the QoS the node offers on it as its ``offered_qos_profiles`` (``layout.BOUNDARY_QOS['last']``:
RELIABLE, TRANSIENT_LOCAL, depth 1 for ``boundary``; ``layout.PER_STEP_QOS`` for the others), so
``ros2 bag play`` replays them to the subscribers the node serves:

* ``<ns>/state`` (``ompn_interfaces/msg/SubtaskState``, the node's ``~/state``: episode, step, π_1..π_n
  lowest slot first, the expected position Σ i·π_i (Lu et al., ICLR 2021, §3.3 π_avg), π_end) and
  ``<ns>/pi`` (``std_msgs/Float32MultiArray``, the same n + 2 values packed as the node's ``~/pi``)
  at the step's observation stamp;
* ``<ns>/segment`` (``std_msgs/Int32``): the segment ordinal of the step (see :data:`SegmentLabels`);
* ``<ns>/boundary`` (``ompn_interfaces/msg/SubtaskBoundary``, the node's ``~/boundary`` event, built by
  :mod:`ompn_ros.data.messages`: node = ``<ns>``, episode = the episode's number from 1,
  ``subtask_id`` from the episode's sketch when it has one, the episode's last event ``final``, the
  episode end included: :func:`~ompn_ros.stream.replay.replay_episode`'s ``published``) logged at
  the stamp of the step where the online detector committed it (``decided_step``; a boundary
  committed on the done step is logged at the final observation's stamp when the episode's stamps
  include it, else at the last real step's).  ``header.frame_id`` is empty.

Opened in Foxglove or PlotJuggler, π then runs under the robot's own data.  The segmentation is the
one :func:`ompn_ros.stream.replay.replay_episode` computes, i.e. the very segmenter ``ompn_node`` runs.

Stamps.  Each episode needs the bag log stamps of its observations (``T`` real steps, optionally the
final observation ``T`` too, used when a boundary was committed on the done step).  Pass them as an
int64 array, or pass the :class:`~ompn_ros.data.episode.Episode` when its reader stored them in
``extras[STAMPS_KEY]``.  :func:`observation_stamps` returns those, or recovers them from the bag
(:func:`match_observation_stamps`) for episodes read from a ``Float32MultiArray`` observation topic.

Complexity: one pass over the input (``O(M)`` messages, each copied once) merged with the
``O(ΣT)`` annotations; memory ``O(ΣT)`` for the annotations only.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import heapq
import json
import re
import shutil
import tempfile
from bisect import bisect_right
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.rosbag2 import WriterError

from ompn_ros import layout
from ompn_ros.app.errors import AnnotateError
from ompn_ros.atomic import make_temp_dir, remove_stale_temps, temp_prefix, write_failure
from ompn_ros.data import messages as m
from ompn_ros.data.episode import OBS_STAMPS, Episode
from ompn_ros.data.recorder.bag_writer import storage_plugin
from ompn_ros.data.recorder.storage import DurableWriter, output_qos
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.layout import resolve_topic
from ompn_ros.segmenter import ReplayResult

Storage = Literal["mcap", "sqlite3"]
SegmentLabels = Literal["boundary", "causal"]
"""How ``<ns>/segment`` labels step ``t``.

* ``'boundary'``: the segment the online boundaries put ``t`` in: the number of boundaries ``b`` with
  ``b.step < t`` (comparable step by step with the ground-truth ``subtask`` topic);
* ``'causal'``: the ordinal the node knew at step ``t``: boundaries already committed
  (``b.detected_at <= t``) and ending before ``t``.  It lags ``'boundary'`` by the commit lag.
"""

STAMPS_KEY = OBS_STAMPS
"""``Episode.extras`` key of the observation log stamps (int64 ``[T + 1]`` or ``[T]``; the bag reader
fills it for every observation kind: Float32MultiArray, JointState, assembled topics)."""

CUSTOM_DATA_KEY = "ompn_ros.annotation"
"""``metadata.yaml`` ``custom_data`` key of the output: JSON with source, namespace, segment_labels."""
SEGMENT = "~/segment"  # Int32: segment ordinal per step (annotated bags only)
STORAGES: tuple[Storage, ...] = ("mcap", "sqlite3")
_ROS_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# order at one stamp: the node publishes events first
_RANK = {"boundary": 1, "state": 2, "pi": 3, "segment": 4}
_INSTALL_ATTEMPTS = 20


@dataclass(frozen=True)
class AnnotateReport:
    """What :func:`annotate_bag` wrote.

    Attributes:
        out: the output bag directory.
        storage: its storage plugin.
        copied: number of input messages copied (all of them).
        added: messages added per output topic (``<ns>/pi``, ``<ns>/segment``, ``<ns>/boundary``).
        episodes: number of annotated episodes.
        steps: number of annotated steps (one ``pi`` and one ``segment`` message each).
    """

    out: Path
    storage: Storage
    copied: int
    added: dict[str, int] = field(default_factory=dict)
    episodes: int = 0
    steps: int = 0


@dataclass(frozen=True)
class _Message:
    stamp: int
    rank: int
    topic: str
    data: bytes


# --- per-episode annotations ----------------------------------------------------------------------
def episode_stamps(source: Episode | np.ndarray | Sequence[int], number: int) -> np.ndarray:
    """Observation log stamps (int64, strictly increasing) of episode ``number`` from an array or
    from ``Episode.extras[STAMPS_KEY]``; :class:`AnnotateError` names the episode otherwise."""
    if isinstance(source, Episode):
        if STAMPS_KEY not in source.extras:
            raise AnnotateError(f"episode #{number} (task '{source.task}', seed {source.seed}) has no "
                                f"extras['{STAMPS_KEY}']: pass its observation stamps explicitly")
        source = source.extras[STAMPS_KEY]
    stamps = np.asarray(source)
    if stamps.ndim != 1 or (stamps.size and not np.issubdtype(stamps.dtype, np.integer)):
        raise AnnotateError(f"episode #{number}: stamps must be a 1-D integer array (ns), "
                            f"got {stamps.dtype} {stamps.shape}")
    stamps = stamps.astype(np.int64)
    if stamps.size > 1 and np.any(np.diff(stamps) <= 0):
        bad = int(np.flatnonzero(np.diff(stamps) <= 0)[0]) + 1
        raise AnnotateError(f"episode #{number}: observation stamps are not strictly increasing "
                            f"(stamp #{bad} = {int(stamps[bad])} ns)")
    return stamps


def segment_labels(boundaries: Iterable[BoundaryEvent], steps: int,
                   labels: SegmentLabels = "boundary") -> np.ndarray:
    """Segment ordinal (int64 ``[steps]``) of every step given the online boundaries (O(T + B))."""
    if labels not in ("boundary", "causal"):
        raise AnnotateError(f"labels must be 'boundary' or 'causal', got {labels!r}")
    delta = np.zeros(steps + 1, dtype=np.int64)
    for b in boundaries:
        # step t is in a later segment once b.step < t (and, causally, once b was committed)
        first = b.step + 1 if labels == "boundary" else max(b.step + 1, b.detected_at)
        if 0 <= first < steps:
            delta[first] += 1
    return np.cumsum(delta[:steps])


def pi_rows(result: ReplayResult) -> np.ndarray:
    """The node's ``~/pi`` values per step: float32 ``[T, n + 2]`` = π_1..π_n, E[pos], π_end."""
    pi = np.asarray(result.pi, dtype=np.float32)
    steps = len(pi)
    if steps == 0:
        return np.zeros((0, 0), dtype=np.float32)
    if pi.ndim != 2 or len(result.expected_position) != steps or len(result.pi_end) != steps:
        raise ValueError(f"replay result: pi {pi.shape}, expected_position {len(result.expected_position)}"
                         f" and pi_end {len(result.pi_end)} do not cover the same steps")
    return np.concatenate([pi, np.asarray(result.expected_position, np.float32)[:, None],
                           np.asarray(result.pi_end, np.float32)[:, None]], axis=1)


def boundary_message(event: BoundaryEvent, stamp_ns: int, node: str, episode: int,
                     sketch: np.ndarray | None, decided_stamp_ns: int) -> bytes:
    """CDR of the node's ``~/boundary`` event for ``event`` (``header.stamp`` = ``stamp_ns``)."""
    return m.encode_subtask_boundary(m.SubtaskBoundary.from_event(
        event, node=node, episode=episode, sketch=sketch, decided_stamp_ns=decided_stamp_ns,
        stamp_ns=stamp_ns))


def episode_messages(stamps: np.ndarray, result: ReplayResult, number: int, topics: dict[str, str],
                     node: str, labels: SegmentLabels = "boundary",
                     sketch: np.ndarray | None = None) -> list[_Message]:
    """The annotation messages of one replayed episode (``number`` from 0), in stamp order (see the
    module docstring)."""
    try:
        rows = pi_rows(result)
    except ValueError as err:
        raise AnnotateError(f"episode #{number}: {err}") from err
    steps = len(rows)
    if len(stamps) not in (steps, steps + 1):
        raise AnnotateError(f"episode #{number}: {len(stamps)} observation stamps for {steps} replayed "
                            f"steps (expected {steps} or {steps + 1} with the final observation)")
    out: list[_Message] = []
    n_slots = rows.shape[1] - 2
    for b in result.published or result.boundaries:  # what the node publishes, the episode end included
        if not 0 <= b.step <= b.detected_at or b.step > steps or b.detected_at > steps:
            raise AnnotateError(f"episode #{number}: boundary at step {b.step} detected at "
                                f"{b.detected_at} lies outside its {steps} steps")
        log_stamp = int(stamps[min(b.detected_at, len(stamps) - 1)])
        out.append(_Message(log_stamp, _RANK["boundary"], topics["boundary"], boundary_message(
            b, int(stamps[min(b.step, len(stamps) - 1)]), node, number + 1, sketch, log_stamp)))
    segments = segment_labels(result.boundaries, steps, labels)
    for t in range(steps):
        stamp = int(stamps[t])
        state = m.encode_subtask_state(stamp, "", number + 1, t, rows[t, :n_slots],
                                                float(rows[t, n_slots]), float(rows[t, n_slots + 1]))
        out.append(_Message(stamp, _RANK["state"], topics["state"], state))
        pi_cdr = m.encode_float32_array(rows[t], layout.PI_LABEL)
        out.append(_Message(stamp, _RANK["pi"], topics["pi"], pi_cdr))
        out.append(_Message(stamp, _RANK["segment"], topics["segment"], m.encode_int32(int(segments[t]))))
    out.sort(key=lambda msg: (msg.stamp, msg.rank))
    return out


def output_topics(namespace: str) -> tuple[dict[str, str], str]:
    """``({'state', 'pi', 'segment', 'boundary'} -> absolute topic, the node's name)`` for ``namespace``."""
    ns = "/" + namespace.strip("/")
    node = ns.rsplit("/", 1)[-1]
    if not node or not all(_ROS_NAME.fullmatch(part) for part in ns.strip("/").split("/")):
        raise AnnotateError(f"namespace must be a ROS name like '/ompn_node', got {namespace!r}")
    topics = {key: resolve_topic(name.removeprefix("~/"), ns)
              for key, name in (("state", layout.STATE), ("pi", layout.PI), ("segment", SEGMENT),
                                ("boundary", layout.BOUNDARY))}
    return topics, ns


def observation_stamps(src: str | Path, episodes: Sequence[Episode], *,
                       topic: str = layout.OBSERVATION, namespace: str = "/") -> list[np.ndarray]:
    """Observation log stamps per episode: ``extras[STAMPS_KEY]`` when every episode has them (the
    bag is then not read), else :func:`match_observation_stamps` on ``src``."""
    if episodes and all(STAMPS_KEY in ep.extras for ep in episodes):
        return [episode_stamps(ep, number) for number, ep in enumerate(episodes)]
    return match_observation_stamps(src, episodes, topic=topic, namespace=namespace)


def match_observation_stamps(src: str | Path, episodes: Sequence[Episode], *,
                             topic: str = layout.OBSERVATION, namespace: str = "/") -> list[np.ndarray]:
    """Log stamps of the observations of ``episodes`` (read from bag ``src``, in bag order).

    Every observation message of ``topic`` is fingerprinted (BLAKE2b of its float32 data); each
    episode row ``t < T`` is matched to the first message after the previous match with the same
    data (exact equality), and the final row ``T`` to the message right after row ``T - 1`` when
    its data equals it (else the episode gets ``T`` stamps: a reader that duplicated the last
    observation).  O(N·D + ΣT·log N) time, O(N) memory.  An observation skipped by the reader
    that equals the next kept one takes its place (same data, earlier stamp).

    Raises:
        AnnotateError: the topic is missing or not ``Float32MultiArray`` (observations assembled
            from other messages: pass their stamps explicitly), or a row is not found.
    """
    path = Path(src)
    reader = _open_reader(path)
    try:
        name = resolve_topic(topic, namespace)
        conns = [c for c in reader.connections if c.topic == name]
        if not conns and not topic.startswith("/"):
            found = sorted({c.topic for c in reader.connections if c.topic.endswith("/" + topic)})
            conns = [c for c in reader.connections if len(found) == 1 and c.topic == found[0]]
        if not conns:
            raise AnnotateError("observation topic not in the bag", path=path, topic=name)
        if any(c.msgtype != layout.FLOAT32_ARRAY for c in conns):
            raise AnnotateError(f"observations are '{conns[0].msgtype}', not Float32MultiArray: pass "
                                "their stamps explicitly", path=path, topic=conns[0].topic)
        stamps, keys = _fingerprints(reader, conns, path)
    finally:
        reader.close()
    positions: dict[bytes, list[int]] = {}
    for i, key in enumerate(keys):
        positions.setdefault(key, []).append(i)
    out = []
    cursor = -1
    for number, episode in enumerate(episodes):
        rows = [_fingerprint(row) for row in np.asarray(episode.observations, dtype=np.float32)]
        found_rows = []
        for t, key in enumerate(rows[:-1]):
            candidates = positions.get(key, [])
            j = bisect_right(candidates, cursor)
            if j == len(candidates):
                raise AnnotateError(f"episode #{number}: observation of step {t} not found after the "
                                    "previous step's", path=path, topic=conns[0].topic)
            cursor = candidates[j]
            found_rows.append(cursor)
        if cursor + 1 < len(keys) and keys[cursor + 1] == rows[-1] and found_rows:
            cursor += 1
            found_rows.append(cursor)
        out.append(stamps[np.asarray(found_rows, dtype=np.int64)])
    return out


def _fingerprint(values: np.ndarray) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(values, dtype="<f4").tobytes(), digest_size=16).digest()


def _fingerprints(reader: Any, conns: list[Any], path: Path) -> tuple[np.ndarray, list[bytes]]:
    """Log stamps (int64, bag order) and data fingerprints of the messages of ``conns``."""
    stamps: list[int] = []
    keys: list[bytes] = []
    try:
        for _, stamp, data in reader.messages(connections=conns):
            keys.append(_fingerprint(m.parse_float32_array(data)))
            stamps.append(int(stamp))
    except Exception as err:
        raise AnnotateError(f"cannot read observation #{len(stamps)}: {type(err).__name__} {err}",
                            path=path, topic=conns[0].topic) from err
    return np.asarray(stamps, dtype=np.int64), keys


# --- bag copy -------------------------------------------------------------------------------------
def _open_reader(src: Path) -> Any:
    from rosbags.rosbag2 import Reader

    if not src.exists():
        raise AnnotateError("no such bag", path=src)
    is_storage = src.is_file() and src.suffix in (".mcap", ".db3")
    if not (is_storage or (src / "metadata.yaml").is_file()):
        raise AnnotateError("not a rosbag2 bag (expected a directory with metadata.yaml, "
                            "or an .mcap/.db3 file)", path=src)
    try:
        reader = Reader(src)
        reader.open()
    except Exception as err:
        raise AnnotateError(f"cannot open bag: {type(err).__name__} {err}", path=src) from err
    return reader


def _prepare_output(out: Path, src: Path, overwrite: bool) -> None:
    """Check ``out`` and remove the staging directories killed writers left beside it.  Each writer
    stages in its own directory (``.<name>.tmp-<pid>-<random>``: runs writing into one folder at
    once never share one), writes the bag into ``staging / out.name`` (so its storage file gets
    ``out``'s own, visible name) and moves it to ``out`` once complete (:func:`_install`)."""
    o, i = out.resolve(), src.resolve()
    if o == i or i in o.parents or o in i.parents:
        raise AnnotateError("the output must not be the input bag, lie inside it or contain it", path=out)
    if out.exists() and not overwrite:
        raise AnnotateError("output exists (ompn_segment --overwrite, or overwrite=True, replaces it)",
                            path=out)
    if not out.parent.is_dir():
        raise AnnotateError("output's parent directory does not exist", path=out)
    remove_stale_temps(out.parent, out.name)


def _install(staged: Path, out: Path) -> None:
    """Rename the complete bag ``staged`` to ``out`` (atomic), replacing what is there: an older copy
    is first renamed aside, then removed.  Concurrent writers of one ``out``: the last one wins, each
    copy whole."""
    for _ in range(_INSTALL_ATTEMPTS):
        if out.is_symlink() or out.is_file():
            out.unlink(missing_ok=True)
        try:
            staged.rename(out)
            return
        except OSError as exc:
            if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                raise
        aside = Path(tempfile.mkdtemp(prefix=temp_prefix(out.name, "old"), dir=out.parent))
        try:
            out.rename(aside / out.name)
        except FileNotFoundError:
            pass  # another writer moved it first
        shutil.rmtree(aside, ignore_errors=True)
    raise AnnotateError(f"could not replace the output in {_INSTALL_ATTEMPTS} attempts: other writers "
                        "keep replacing it", path=out)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _copy_connections(reader: Any, writer: Any, src: Path) -> dict[int, Any]:
    """Output connection per input connection id (identical topic/type/QoS share one)."""
    ts = m.typestore()
    by_key: dict[tuple[str, str, str, str], Any] = {}
    mapping: dict[int, Any] = {}
    for conn in reader.connections:
        ext = conn.ext
        fmt = getattr(ext, "serialization_format", "cdr")
        qos = list(getattr(ext, "offered_qos_profiles", []))
        key = (conn.topic, conn.msgtype, fmt, repr(qos))
        if key not in by_key:
            msgdef = conn.msgdef.data if conn.msgdef.data and conn.digest else None
            if msgdef is None and conn.msgtype not in ts.types:
                raise AnnotateError(f"type '{conn.msgtype}' has no message definition in the bag and "
                                    "is not in the ROS 2 Jazzy typestore", path=src, topic=conn.topic)
            by_key[key] = writer.add_connection(
                conn.topic, conn.msgtype, typestore=ts, msgdef=msgdef,
                rihs01=conn.digest if msgdef is not None else None,
                serialization_format=fmt, offered_qos_profiles=qos)
        mapping[conn.id] = by_key[key]
    return mapping


def _all_annotations(episodes_outputs: Sequence[tuple[Episode | np.ndarray | Sequence[int], ReplayResult]],
                     topics: dict[str, str], node: str, labels: SegmentLabels,
                     sketches: Sequence[np.ndarray | None] | None = None) -> tuple[list[_Message], int]:
    messages: list[_Message] = []
    steps = 0
    for number, (source, result) in enumerate(episodes_outputs):
        stamps = episode_stamps(source, number)
        sketch = source.sketch if isinstance(source, Episode) else None
        if sketches is not None and number < len(sketches):
            sketch = sketches[number]
        part = episode_messages(stamps, result, number, topics, node, labels, sketch)
        steps += len(result.pi)
        messages.extend(part)
    messages.sort(key=lambda msg: (msg.stamp, msg.rank))
    return messages, steps


def _input(reader: Any, src: Path) -> Iterator[tuple[Any, int, bytes | memoryview]]:
    """The input's messages; a failed read (a bag that vanished, a corrupt chunk) names the input."""
    count = 0
    try:
        for item in reader.messages():
            yield item
            count += 1
    except Exception as err:
        raise AnnotateError(f"cannot read message #{count} of the input: {type(err).__name__} {err}",
                            path=src) from err


def _merged(reader: Any, mapping: dict[int, Any], added: list[_Message],
            out_conns: dict[str, Any], src: Path) -> Iterator[tuple[int, int, Any, bytes | memoryview]]:
    """Input messages (rank 0: first at equal stamps) merged with the annotations by stamp."""
    original = ((stamp, 0, mapping[conn.id], data) for conn, stamp, data in _input(reader, src))
    extra = ((msg.stamp, msg.rank, out_conns[msg.topic], msg.data) for msg in added)
    return heapq.merge(original, extra, key=lambda item: (item[0], item[1]))


def annotate_bag(
    src: str | Path,
    out: str | Path,
    episodes_outputs: Sequence[tuple[Episode | np.ndarray | Sequence[int], ReplayResult]],
    *,
    namespace: str = "/ompn_node",
    storage: Storage = "mcap",
    overwrite: bool = False,
    labels: SegmentLabels = "boundary",
    sketches: Sequence[np.ndarray | None] | None = None,
) -> AnnotateReport:
    """Write ``out``: a copy of bag ``src`` plus the node's ``pi``/``segment``/``boundary`` topics.

    Args:
        src: the recording (bag directory, or an ``.mcap``/``.db3`` storage file).
        out: the new bag directory (rosbag2 metadata v9).
        episodes_outputs: per replayed episode, ``(stamps, result)``: the observation log stamps
            (int64 ``[T]`` or ``[T + 1]``, or an ``Episode`` holding them in ``extras[STAMPS_KEY]``)
            and its :class:`~ompn_ros.segmenter.ReplayResult`.
        namespace: the node namespace of the added topics (``<ns>/pi`` ...).
        storage: ``'mcap'`` (default) or ``'sqlite3'``.
        overwrite: replace an existing ``out`` (refused otherwise).
        labels: the ``segment`` labelling rule (:data:`SegmentLabels`).
        sketches: per episode, its sketch (``subtask_id`` of the boundary events); by default the
            sketch of an ``Episode`` given as the stamps, else none (``subtask_id`` −1).

    Raises:
        AnnotateError: naming the bag, topic or episode at fault; ``out`` is then left untouched.
    """
    src, out = Path(src), Path(out)
    if storage not in STORAGES:
        raise AnnotateError(f"storage must be one of {STORAGES}, got {storage!r}")
    topics, node = output_topics(namespace)
    added, steps = _all_annotations(episodes_outputs, topics, node, labels, sketches)
    _prepare_output(out, src, overwrite)
    reader = _open_reader(src)
    tmp: Path | None = None
    try:
        tmp = make_temp_dir(out.parent, out.name)
        clash = sorted({c.topic for c in reader.connections} & set(topics.values()))
        if clash:
            raise AnnotateError("the input already has this topic; annotate under another namespace",
                                path=src, topic=clash[0])
        note = json.dumps({"source": src.name, "namespace": "/" + namespace.strip("/"),
                           "segment_labels": labels})
        copied = _write(reader, tmp / out.name, storage, topics, added, src, note, out)
        _install(tmp / out.name, out)
    finally:
        reader.close()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    counts = Counter(msg.topic for msg in added)
    return AnnotateReport(out=out, storage=storage, copied=copied,
                          added={topic: counts[topic] for topic in topics.values()},
                          episodes=len(episodes_outputs), steps=steps)


def _write(reader: Any, tmp: Path, storage: Storage, topics: dict[str, str], added: list[_Message],
           src: Path, note: str, out: Path) -> int:
    """Copy ``reader`` (messages and ``custom_data``) and the annotations into a new bag at ``tmp``,
    recording ``note`` under ``custom_data[CUSTOM_DATA_KEY]``; the number of copied messages.  A
    failed write (a full disk...) is one :class:`~ompn_ros.errors.WriteFailure` line naming ``out``."""
    writer = DurableWriter(tmp, version=9, storage_plugin=storage_plugin(storage), commit_period=None)
    custom = getattr(getattr(reader.storage, "metadata", None), "custom", None) or {}
    for key, value in custom.items():
        if isinstance(key, str) and isinstance(value, str):
            writer.set_custom_data(key, value)
    writer.set_custom_data(CUSTOM_DATA_KEY, note)
    try:
        writer.open()
        copied = _copy_all(reader, writer, topics, added, src)
    except BaseException as exc:
        with contextlib.suppress(Exception):  # closing a failed copy may fail again: the first error counts
            writer.close()
        if isinstance(exc, (OSError, WriterError)) and not isinstance(exc, AnnotateError):
            raise write_failure(out, exc, "; no copy was written") from exc
        raise
    try:
        writer.close()
    except (OSError, WriterError) as exc:  # the last chunk and metadata.yaml are written here
        raise write_failure(out, exc, "; no copy was written") from exc
    return copied


def _copy_all(reader: Any, writer: Any, topics: dict[str, str], added: list[_Message], src: Path) -> int:
    """Copy every input message and the annotations into the open ``writer``; the number copied."""
    mapping = _copy_connections(reader, writer, src)
    ts = m.register_interfaces()
    types = {"state": m.SUBTASK_STATE, "pi": layout.FLOAT32_ARRAY, "segment": layout.INT32,
             "boundary": m.SUBTASK_BOUNDARY}
    qos = {key: layout.PER_STEP_QOS for key in types} | {"boundary": layout.BOUNDARY_QOS["last"]}
    out_conns = {topic: writer.add_connection(topic, types[key], typestore=ts,
                                              offered_qos_profiles=[output_qos(qos[key])])
                 for key, topic in topics.items()}
    copied = 0
    try:
        for stamp, rank, conn, data in _merged(reader, mapping, added, out_conns, src):
            writer.write(conn, stamp, data)
            copied += rank == 0
    except (AnnotateError, OSError, WriterError):
        raise  # a full or read-only disk: write_failure names the space left
    except Exception as err:
        raise AnnotateError(f"copy failed after {copied} messages: {type(err).__name__} {err}",
                            path=src) from err
    return copied


__all__ = [
    "CUSTOM_DATA_KEY",
    "STAMPS_KEY",
    "AnnotateReport",
    "SegmentLabels",
    "annotate_bag",
    "boundary_message",
    "episode_messages",
    "episode_stamps",
    "match_observation_stamps",
    "observation_stamps",
    "output_topics",
    "pi_rows",
    "segment_labels",
]
