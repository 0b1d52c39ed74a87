"""One bag being recorded live: each message goes through the stop cut, then the step commits, then
the durable writer; the per-topic statistics; the first storage failure stops the recording.

The part of ``bag_recorder`` that writes (the node keeps the subscriptions, the stamps and the
drain).  A failed write or commit (a full disk, any storage error) is logged once, the disk reserve
of :class:`~ompn_ros.data.recorder.disk_guard.DiskGuard` is released and nothing more is written,
so that :meth:`Recording.close` can still close the bag properly.
"""

from __future__ import annotations

import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from rosbags.interfaces import Qos

from ompn_ros.data import messages as m

from .bag_writer import storage_plugin
from .disk_guard import DiskGuard
from .step_commits import COMMIT, StepCommits
from .stop_cut import StopCut
from .storage import DurableWriter

RESERVE_BYTES = 2 * 1024 * 1024  # kept free beside the bag so that a full disk still lets it close
STREAM_PERIOD_S = 0.5  # a topic publishing at least every 0.5 s is a stream the drain waits for


class Log(Protocol):
    """Where the recording reports (the node's logger)."""

    def warning(self, message: str) -> object: ...

    def error(self, message: str) -> object: ...


@dataclass
class TopicStats:
    """Per-topic recording statistics."""

    msgtype: str
    count: int = 0  # messages written
    received: int = 0  # messages taken from DDS
    last_seq: int | None = None
    lost: int = 0  # messages missing according to publication sequence numbers
    last_stamp: int | None = None
    time_gaps: list[float] = field(default_factory=list)
    receive_stamps: int = 0  # messages written at receive time (no source timestamp)
    last_src: int | None = None  # source stamp of the last message taken
    period_ns: float | None = None  # running mean of the source-stamp spacing

    def taken(self, src: int) -> None:
        """Track the spacing of the messages taken (for :meth:`streaming`)."""
        if self.last_src is not None and src > self.last_src:
            gap = float(src - self.last_src)
            self.period_ns = gap if self.period_ns is None else 0.9 * self.period_ns + 0.1 * gap
        self.last_src = src if self.last_src is None else max(self.last_src, src)

    def streaming(self, at_ns: int) -> bool:
        """A message at least every ``STREAM_PERIOD_S`` and one in the last second before ``at_ns``."""
        return (self.period_ns is not None and self.period_ns < STREAM_PERIOD_S * 1e9
                and self.last_src is not None and at_ns - self.last_src < 1e9)


@dataclass
class RecordedTopic:
    """A topic of the bag: its connection and statistics."""

    name: str
    conn: Any
    stats: TopicStats


Item = tuple[RecordedTopic, int, bytes]
"""A message on its way to the bag: its topic, its stamp in the bag, its bytes."""


class Recording:
    """The bag ``output`` being written (``storage``: ``mcap`` or ``sqlite3``).

    Args:
        step: the topic that opens a step (the stop cut and the step commits), ``None``: none.
        commit_period: seconds between storage commits.
        min_free_bytes: free space needed to start (``NotEnoughSpace``, an ``OSError``, otherwise).
        gap_ns: a per-topic stamp jump larger than this is counted as a time gap.
    """

    def __init__(self, output: Path, storage: str, step: str | None, commit_period: float,
                 min_free_bytes: int, gap_ns: int, log: Log) -> None:
        self.output = output
        self.gap_ns = gap_ns
        self.log = log
        self.cut: StopCut[Item] = StopCut(step)
        self.commits: StepCommits[Item] = StepCommits(step, commit_period)
        self.topics: dict[str, RecordedTopic] = {}
        self.write_errors = 0
        self.failed = ""  # the storage error that stopped the recording
        self.disk = DiskGuard(output, min_free_bytes, RESERVE_BYTES)
        self.disk.start()  # NotEnoughSpace (an OSError: exit 2) before anything is created
        self._space_checked = time.monotonic()
        self.writer: DurableWriter | None = DurableWriter(
            output, version=9, storage_plugin=storage_plugin(storage), commit_period=None)
        try:
            self.writer.open()
        except BaseException:
            self.disk.release()
            raise

    def add_topic(self, name: str, msgtype: str, offered: list[Qos]) -> RecordedTopic:
        """A new topic of the bag (``offered``: its publishers' QoS profiles, as rosbag2 stores them)."""
        assert self.writer is not None  # topics are added while recording
        conn = self.writer.add_connection(name, msgtype, typestore=m.typestore(),
                                          offered_qos_profiles=offered)
        topic = self.topics[name] = RecordedTopic(name, conn, TopicStats(msgtype))
        return topic

    def offer(self, topic: RecordedTopic, src: int, stamp: int, raw: bytes) -> None:
        """One message taken (``src``: its source stamp, ``stamp``: its stamp in the bag)."""
        for item in self.cut.offer(topic.name, src, (topic, stamp, raw)):
            self._apply(self.commits.offer(topic.name, stamp, item, self._since_commit()))

    def _since_commit(self) -> float:
        return self.writer.since_checkpoint() if self.writer is not None else 0.0

    def _apply(self, actions: list[Item | Any]) -> None:
        """Write the messages and make the commits :class:`StepCommits` decided, in order."""
        for action in actions:
            if action is COMMIT:
                self._checkpoint()
            else:
                self._write(*action)

    def _checkpoint(self) -> None:
        if self.writer is not None and not self.failed:
            try:
                self.writer.checkpoint()
            except (OSError, sqlite3.Error) as err:
                self._storage_failed(err)

    def _storage_failed(self, err: Exception) -> None:
        """The first failed write or commit stops the recording: one line, the reserve released for
        the close (the main loop then closes the bag and exits 2)."""
        if self.failed:
            return
        self.disk.release()
        self.failed = (f"stopped recording: cannot write to '{self.output}': {err} "
                       f"({self.disk.free_text()}); closing the bag with what was written")
        self.log.error(self.failed)

    def _write(self, topic: RecordedTopic, stamp: int, raw: bytes) -> None:
        writer = self.writer
        if writer is None:
            return
        if self.failed:
            self.write_errors += 1
            return
        try:
            writer.write(topic.conn, stamp, raw)
        except (OSError, sqlite3.Error) as err:  # disk full, ...: the recording stops, the bag is closed
            self.write_errors += 1
            self._storage_failed(err)
            return
        stats = topic.stats
        stats.count += 1
        if stats.last_stamp is not None and stamp - stats.last_stamp > self.gap_ns:
            stats.time_gaps.append((stamp - stats.last_stamp) / 1e9)
        stats.last_stamp = stamp

    def tick(self) -> None:
        """Periodic: a pending commit a whole period old is made anyway; with none pending and a
        period over (no step opened in half of one), the storage is committed."""
        writer = self.writer
        if writer is not None and not self.failed:
            self._apply(self.commits.due(writer.since_checkpoint()))
            if self.commits.idle_commit(writer.since_checkpoint()):
                self._checkpoint()
        now = time.monotonic()
        if now - self._space_checked >= 1.0:  # one statvfs a second
            self._space_checked = now
            low = self.disk.low()
            if low is not None:
                self.log.warning(low)

    def finish(self) -> None:
        """Write what the stop cut and the pending commit hold back (the recording ends)."""
        for item in self.cut.finish():
            self._apply(self.commits.offer(item[0].name, item[1], item, self._since_commit()))
        self._apply(self.commits.flush())

    def close(self) -> None:
        """Close the bag (after :meth:`finish`); a bag that cannot be closed is logged and ``failed``."""
        if self.writer is not None:
            try:
                self.writer.close()
            except (OSError, sqlite3.Error) as err:  # even the reserve did not suffice
                self.failed = self.failed or f"cannot write to '{self.output}': {err}"
                self.log.error(f"the bag could not be closed ({err}): read it with --on-error "
                               "skip_tail (ompn_train: --set data.on_error=skip_tail)")
            self.writer = None
        self.disk.release()

    def topic_lines(self) -> list[str]:
        """One summary line per recorded topic: messages, sequence jumps, time gaps, receive stamps."""
        lines = []
        for name in sorted(self.topics):
            s = self.topics[name].stats
            line = f"  {name} [{s.msgtype}]: {s.count} messages"
            if s.lost:
                line += f", {s.lost} lost (sequence jumps)"
            if s.time_gaps:
                line += (f", {len(s.time_gaps)} time gap(s) > {self.gap_ns / 1e9:g} s "
                         f"(max {max(s.time_gaps):.2f} s)")
            if s.receive_stamps:
                line += f", {s.receive_stamps} stamped at receive time"
            lines.append(line)
        return lines
