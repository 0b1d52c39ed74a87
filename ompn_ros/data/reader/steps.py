"""Clocks that step: a stamp that steps back or jumps forward within a bag.

Two clocks stamp a bag's messages: the recording PC's (log stamps: rosbag2's receive time) and, for
topics with a header, the robot's (``header.stamp``).  Either may step: an NTP correction sets it
back or forward by seconds in one go.  Sorted by stamp and cut at gaps, a stepped clock merges
demonstrations (back), splits one (forward) or attaches partners to other observations.  The reader
keeps each topic in recording order instead and never lets a step reshape a demonstration:

* **the log clock steps back**: found in record order (sqlite3 message ids, mcap message indexes;
  ``rosbags`` hands messages over sorted by log stamp), read as recorded: every stamp recorded after
  the step is moved on by its size, so the bag's own order stands, and a note names the topic, the
  place and the size (:func:`restamp_log`).
* **the log clock jumps forward** (seen against the header clock of a JointState topic that does
  not jump): read as recorded, the later stamps moved back by the jump less one period, noted.
* **a header clock steps** (back, or forward against the log clock) on a topic read with
  ``stamp: header``: refused with one line naming topic, message, size and the fix ``stamp: log``
  (:func:`check_header_steps`); on a topic read on the log clock it changes nothing.

A step is a change of the log − header lag of at least :data:`STEP_NS` that lasts (the median lag of
the :data:`SETTLE` messages after it differs from that of the ones before by as much: a message
delivered late is no step), or a stamp at least :data:`STEP_NS` earlier than the one recorded before
it on the same topic.  The clock that moved is the one whose interval differs from its topic's
period; a pause shows on both clocks alike (:mod:`ompn_ros.data.clock_steps`, the rule the node
applies live too).  A forward jump of the log clock in a bag without header
stamps looks exactly like a pause: it is read as one.  Cost: one pass over the message indexes
(16 bytes a message) and O(N) per topic.
"""

from __future__ import annotations

import sqlite3
import struct
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from ..clock_steps import STEP_NS, header_moved
from ..errors import ClockStepError
from .raw import RawBag
from .verify import open_readonly

SETTLE = 5
"""Messages on each side of a lag change whose medians must show it (a late message is no step)."""
MAX_STEPS = 8
"""More lag changes than this in one topic are no clock steps but two unrelated clocks (the stamps
check of :mod:`.clocks` judges those)."""


@dataclass(frozen=True)
class Step:
    """One clock step on ``topic``: before message ``index`` (per topic, record order), ``size`` ns
    (negative: back), ``stamp`` the stamp of that message as recorded."""

    topic: str
    index: int
    size: int
    stamp: int

    def text(self, clock: str) -> str:
        way = "back" if self.size < 0 else "forward"
        return (f"the {clock} clock steps {way} {abs(self.size) / 1e9:.3f} s on '{self.topic}' at message "
                f"#{self.index} (stamped {self.stamp} ns)")


def restamp_log(raw: RawBag, readable: Path, header_topics: list[str]) -> list[str]:
    """Undo steps of the log clock on every topic of ``raw`` (module docstring); the notes to report.

    ``header_topics``: JointState topics whose header stamps show a forward jump of the log clock."""
    notes: list[str] = []
    order = record_order_stamps(readable, set(raw.topics))
    back = _back_steps(order)
    if back:
        sizes = [min(steps[k].size for steps in back.values() if len(steps) > k)
                 for k in range(max(len(steps) for steps in back.values()))]
        for topic, steps in back.items():
            _shift(raw, topic, order[topic], steps, sizes)
        first = min((steps[0] for steps in back.values()), key=lambda s: s.stamp)
        notes.append(f"{first.text('recording PC')} ({len(sizes)} step(s) back): read in recording "
                     "order, the stamps after each step moved on by its size")
    for topic in header_topics:
        for step in _forward_log_jumps(raw, topic):
            _shift_after(raw, step.stamp, step.size)
            notes.append(f"{step.text('recording PC')}, its header clock does not: read as recorded, the "
                         "later stamps moved back by the jump")
    if notes and raw.assembly is not None:
        raw.assembly = None  # built on the stepped stamps: rebuilt from the bytes (reader.observe)
    return notes


def record_order_stamps(bag: Path, topics: set[str]) -> dict[str, np.ndarray]:
    """Log stamps of ``topics`` in record order, per topic (empty where the storage cannot say:
    an mcap file without index, a compressed file)."""
    files = [bag] if bag.is_file() else sorted(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    parts: dict[str, list[np.ndarray]] = {}
    for file in files:
        found = _sqlite_order(file, topics) if file.suffix == ".db3" else _mcap_order(file, topics)
        for topic, stamps in found.items():
            parts.setdefault(topic, []).append(stamps)
    return {t: np.concatenate(p) for t, p in parts.items()}


STEPS_BACK = ("SELECT 1 FROM messages a JOIN messages b ON b.id = a.id + 1 "
              "WHERE b.timestamp <= a.timestamp - ? LIMIT 1")
"""Whether a message is stamped a step earlier than the one recorded before it (any topic): one pass of
rowid lookups inside SQLite, about 0.2 us a message."""


def _sqlite_order(file: Path, topics: set[str]) -> dict[str, np.ndarray]:
    """Per topic, in message id order; nothing when no stamp steps back (the usual bag: one query)."""
    con = open_readonly(file)
    try:
        ids = {tid: name for tid, name in con.execute("SELECT id, name FROM topics") if name in topics}
        if con.execute(STEPS_BACK, (STEP_NS,)).fetchone() is None:
            return {}
        out: dict[str, np.ndarray] = {}
        for tid, name in ids.items():
            rows = con.execute("SELECT timestamp FROM messages WHERE topic_id = ? ORDER BY id", (tid,))
            out[name] = np.fromiter((r[0] for r in rows), dtype=np.int64)
        return out
    except sqlite3.Error:
        return {}
    finally:
        con.close()


def _mcap_order(file: Path, topics: set[str]) -> dict[str, np.ndarray]:
    """From the message index records of each chunk (file order, then offset in the chunk)."""
    try:
        with open(file, "rb") as fh:
            summary = make_reader(fh).get_summary()
            if summary is None or not summary.chunk_indexes:
                return {}
            channels = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in topics}
            parts: dict[str, list[np.ndarray]] = {t: [] for t in channels.values()}
            for chunk in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
                for cid, offset in chunk.message_index_offsets.items():
                    if cid in channels:
                        parts[channels[cid]].append(_index_stamps(fh, offset))
            return {t: np.concatenate(p) if p else np.zeros(0, np.int64) for t, p in parts.items()}
    except (OSError, ValueError, struct.error, KeyError, AttributeError):
        return {}
    except Exception:  # the mcap reader raises its own types on a file without a usable summary
        return {}


def _index_stamps(fh: object, offset: int) -> np.ndarray:
    """Log stamps of one MessageIndex record (opcode, length, channel, entries of stamp and offset)."""
    fh.seek(offset)  # type: ignore[attr-defined]
    head = fh.read(1 + 8 + 2 + 4)  # type: ignore[attr-defined]
    (size,) = struct.unpack_from("<I", head, 11)
    entries = np.frombuffer(fh.read(size), dtype="<u8").reshape(-1, 2)  # type: ignore[attr-defined]
    entries = entries[np.argsort(entries[:, 1], kind="stable")]  # by offset: the record order
    return entries[:, 0].astype(np.int64)


def _back_steps(order: dict[str, np.ndarray]) -> dict[str, list[Step]]:
    """Per topic (record order), every stamp at least :data:`STEP_NS` earlier than the one before it;
    ``Step.size`` counts one period more (the interval the step took the place of)."""
    out: dict[str, list[Step]] = {}
    for topic, stamps in order.items():
        diff = np.diff(stamps)
        found = [Step(topic, i + 1, int(diff[i]) - _period(diff), int(stamps[i + 1]))
                 for i in np.flatnonzero(diff <= -STEP_NS).tolist()]
        if found:
            out[topic] = found
    return out


def _period(diff: np.ndarray) -> int:
    forward = diff[diff > 0]
    return int(np.median(forward)) if forward.size else 0


def _shift(raw: RawBag, topic: str, recorded: np.ndarray, steps: list[Step], sizes: list[int]) -> None:
    """Move on the stamps of ``topic`` recorded after its k-th back step by ``-sizes[k]`` (the bag's
    k-th step, the largest any topic measured: one PC clock stamps them all).  ``raw`` holds them
    sorted by stamp (``rosbags`` order) and ``recorded`` in record order; a stamp finds its place in
    record order by value."""
    tdata = raw.topics[topic]
    offset = np.zeros(len(recorded), dtype=np.int64)
    for step, size in zip(steps, sizes):
        offset[step.index:] -= size
    key = np.argsort(recorded, kind="stable")
    values = np.asarray(tdata.stamps, dtype=np.int64)
    at = np.clip(np.searchsorted(recorded[key], values), 0, len(key) - 1)
    tdata.stamps = array("q", (values + offset[key][at]).tolist())


def _forward_log_jumps(raw: RawBag, topic: str) -> list[Step]:
    """Forward jumps of the log clock seen against ``topic``'s header stamps (which do not jump).

    Only the messages around an interval of :data:`STEP_NS` or more (a pause, or a jump) have their
    header stamps read: :data:`SETTLE` on each side.  O(N) in NumPy plus O(pauses) messages."""
    tdata = raw.topics.get(topic)
    if tdata is None or not tdata.has_raws or tdata.column is not None or len(tdata.raws) < 2:
        return []
    log = np.asarray(tdata.stamps, dtype=np.int64)
    gaps = np.flatnonzero(np.diff(log) >= STEP_NS)  # pauses, or jumps: the header stamps tell which
    ends = header_stamps([tdata.raws[k] for i in gaps.tolist() for k in (i, i + 1)])
    if ends is None or not gaps.size:
        return []
    moved = np.abs(np.diff(log)[gaps] - (ends[1::2] - ends[::2])) >= STEP_NS
    found: list[Step] = []
    for i in gaps[moved].tolist():
        a, b = max(0, i + 1 - SETTLE), min(len(log), i + 1 + SETTLE)
        header = header_stamps(tdata.raws[a:b])
        if header is None:
            return []
        found.extend(_shifted(step, a) for step, clock in lag_steps(topic, log[a:b], header, window=True)
                     if clock == "log" and step.size > 0 and step.index == i + 1 - a)
    return found


def _shifted(step: Step, offset: int) -> Step:
    return Step(step.topic, step.index + offset, step.size, step.stamp)


def header_stamps(raws: list[bytes]) -> np.ndarray | None:
    """``header.stamp`` (ns) of little-endian CDR messages whose first field is a Header (None: other)."""
    try:
        head = np.frombuffer(b"".join(r[:12] for r in raws), dtype=np.uint8).reshape(len(raws), 12)
    except ValueError:
        return None
    if np.any(head[:, 1] != 1):  # encapsulation: CDR little endian
        return None
    sec = head[:, 4:8].copy().view("<i4").astype(np.int64).ravel()
    nsec = head[:, 8:12].copy().view("<u4").astype(np.int64).ravel()
    return sec * 1_000_000_000 + nsec


def lag_steps(topic: str, log: np.ndarray, header: np.ndarray,
              window: bool = False) -> list[tuple[Step, str]]:
    """Lasting changes of the log − header lag of one topic (both in record order), each with the
    clock that moved (``'log'`` or ``'header'``: the one whose interval left its period, or went
    back).  ``Step.size`` is that clock's step.  ``window``: the arrays are the messages around one
    candidate only (no limit on the changes found elsewhere)."""
    if len(log) < 2 or np.any(header <= 0):
        return []  # an unset header (refused where it is used) says nothing about either clock
    lag = log - header
    dlag = np.diff(lag)
    dlog, dhead = np.diff(log), np.diff(header)
    plog, phead = _period(dlog), _period(dhead)
    candidates = np.flatnonzero(np.abs(dlag) >= STEP_NS)
    if plog <= 0 or phead <= 0 or (candidates.size > MAX_STEPS and not window):
        return []  # no steady pair of clocks (e.g. publishers on different clocks): no step pattern
    out: list[tuple[Step, str]] = []
    for i in candidates.tolist():
        before = np.median(lag[max(0, i + 1 - SETTLE): i + 1])
        after = np.median(lag[i + 1: i + 1 + SETTLE])
        if abs((after - before) - dlag[i]) > STEP_NS // 2:
            continue  # a message delivered late, not a step
        if header_moved(int(dlog[i]), int(dhead[i]), plog, phead):
            out.append((Step(topic, i + 1, int(dhead[i] - phead), int(header[i + 1])), "header"))
        else:
            out.append((Step(topic, i + 1, int(dlog[i] - plog), int(log[i + 1])), "log"))
    return out


def _shift_after(raw: RawBag, stamp: int, size: int) -> None:
    """Move back by ``size`` every log stamp at or after ``stamp`` (a forward jump of the log clock)."""
    for tdata in raw.topics.values():
        values = np.asarray(tdata.stamps, dtype=np.int64)
        tdata.stamps = array("q", np.where(values >= stamp, values - size, values).tolist())


def check_header_steps(path: str, topic: str, log: np.ndarray, header: np.ndarray) -> None:
    """Raise :class:`ClockStepError` when ``topic``'s header clock steps (read with ``stamp: header``)."""
    for step, clock in lag_steps(topic, log, header):
        if clock == "header":
            way = "back" if step.size < 0 else "forward"
            raise ClockStepError(
                f"header.stamp steps {way} {abs(step.size) / 1e9:.3f} s at this message (the log clock "
                f"does not): the robot's clock stepped, and sorted by it demonstrations would merge, "
                "split or reorder; read with stamp: log", path=path, topic=topic, index=step.index)


__all__ = ["STEP_NS", "Step", "check_header_steps", "header_stamps", "lag_steps", "record_order_stamps",
           "restamp_log"]
