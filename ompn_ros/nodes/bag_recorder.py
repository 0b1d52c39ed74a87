"""``bag_recorder``: record the sim topics to a rosbag2 (v9, mcap or sqlite3) without decoding.

Usage: ``bag_recorder [TOPIC ...] [-o OUTPUT] [-s {mcap,sqlite3}] [--ros-args -p name:=value ...]``
(``bag_recorder --help`` lists every parameter with its default and has no other effect).

Parameters (``-p name:=value``; the positional topics, ``-o`` and ``-s`` set the first three):
    topics (string[]): topics to record; relative names resolve in the node's namespace.
        Default: every topic the sims publish (``ompn_ros.layout``).
    output (string): bag directory to create; default ``bags/rec_<UTC timestamp>``.
    storage (string): ``mcap`` (default) or ``sqlite3``.
    qos_depth (int): 0 (default) = KEEP_ALL history: DDS never discards a message the recorder has
        not taken yet (a reliable publisher waits instead); N > 0 = KEEP_LAST N (a stall longer than
        N messages loses the oldest ones, counted as sequence jumps).
    discovery_period (double): seconds between topic discovery passes (default 0.2, steady clock).
    gap_seconds (double): a per-topic stamp jump larger than this is reported as a time gap.
    step_topic (string): the topic that opens a step (default ``observation``); on stop every topic
        ends right before its first message published after the signal.  If it is not recorded, the
        one recorded topic with the same base name is used; '' or no such topic = end at the signal.
    drain_timeout (double): longest drain after SIGINT/SIGTERM, in seconds (default 10).
    drain_idle (double): with no stream waiting (below), the drain ends once nothing was written
        for this long (default 0.3 s).  It ends at once when every topic that was streaming at the
        signal (a message at least every 0.5 s, the last within 1 s) has delivered a message from the
        cut on; a stalled stream is waited for (up to ``drain_timeout``) while its publisher lives.
    min_free_mb (double): free space needed to start, warned about once when it runs low (default 64).
    commit_period (double): seconds between storage commits (default 1.0): a SIGKILL loses at most
        this much (sqlite3 COMMIT; mcap chunk with CRC flushed to the file).  Once half the period
        has passed, the next step's opening message is held back with everything stamped after it
        until every other streaming topic has delivered its messages stamped before it; then the
        commit is made, so a killed recording ends with whole steps (``ompn_ros.data.recorder.step_commits``).

Subscriptions are ``raw=True`` (CDR bytes go to the bag untouched), RELIABLE + VOLATILE (compatible
with both volatile and transient-local publishers).  Topics are subscribed as they appear
(``get_topic_names_and_types``), each with its discovered type.

**Stamps:** every message is written at the publisher's ``source_timestamp`` from the message info
that rclpy 7.1.6 passes to a two-argument subscription callback (falling back to
``received_timestamp`` if a middleware gives none).  Source stamps keep the publish order of the
step contract across topics, whatever the delivery order.  Under ``use_sim_time`` the stamps are
moved into the input's (sim) time base: a step is stamped at the sim time its opening message
arrived, its messages keep their publish order (``ompn_ros.data.recorder.sim_stamps``).  Messages taken
before the first ``/clock`` wait for it (up to 20 000, then they are written in system time).
Loss is detected from ``publication_sequence_number`` jumps per topic (a backwards jump = another
publisher, not counted).

**A full disk** (or any storage error): recording stops at the first failed write or commit, with
one error line naming the bag and the free space; the recorder then closes the bag properly
(``metadata.yaml``, the mcap summary and footer, the sqlite3 COMMIT: room for them is kept by
:class:`ompn_ros.data.recorder.disk_guard.DiskGuard`) and exits with status 2, so what was written
opens without
``skip_tail``.  Less than ``min_free_mb`` free at start is refused (exit 2); falling below it while
recording is warned once.

**Stopping:** SIGINT/SIGTERM do not drop the queue.  The recorder drains what DDS has delivered and
ends every topic at the same step (``ompn_ros.data.recorder.stop_cut``), closes the bag and prints a summary
(messages per topic, sequence jumps, large time gaps, the drain).  A second signal ends the drain
at once (the bag is still closed properly).
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import sqlite3
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import STORAGES, storage_plugin
from ompn_ros.data.recorder.disk_guard import DiskGuard
from ompn_ros.data.recorder.sim_stamps import SimStamper
from ompn_ros.data.recorder.step_commits import COMMIT, StepCommits
from ompn_ros.data.recorder.stop_cut import StopCut
from ompn_ros.data.recorder.storage import DurableWriter, offered_qos
from ompn_ros.errors import OMPNError
from ompn_ros.ros.params import ParamSpec, ParamTable
from ompn_ros.ros.run import NodeProcess, run_node

NODE_NAME = "bag_recorder"
USAGE = "[TOPIC ...] [-o OUTPUT] [-s {mcap,sqlite3}]"
DEFAULT_TOPICS = [
    layout.EPISODE_MARKER, layout.EPISODE, layout.SKETCH, layout.OBSERVATION, layout.JOINT_STATES,
    layout.SUBTASK, layout.ACTION, layout.RENDER,
]
# The single table behind the declared parameters and --help (ompn_ros.ros.params).
PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("topics", DEFAULT_TOPICS, "topics to record (relative names follow the node's namespace)"),
    ParamSpec("output", "", "bag directory to create ('' = bags/rec_<UTC timestamp>)"),
    ParamSpec("storage", "mcap", "storage plugin", choices=STORAGES),
    ParamSpec("qos_depth", 0, "0 = KEEP_ALL (DDS drops nothing not yet taken); N > 0 = KEEP_LAST N",
              int_range=(0, 1_000_000)),
    ParamSpec("discovery_period", 0.2, "seconds between topic discovery passes", float_range=(0.001, 60.0)),
    ParamSpec("gap_seconds", 0.5, "report per-topic stamp jumps larger than this (seconds)",
              float_range=(0.001, 3600.0)),
    ParamSpec("step_topic", layout.OBSERVATION, "topic opening a step; on stop all topics end before its "
              "first message after the signal ('' = end at the signal)"),
    ParamSpec("drain_timeout", 10.0, "longest drain after SIGINT/SIGTERM (seconds)",
              float_range=(0.001, 3600.0)),
    ParamSpec("drain_idle", 0.3, "with no live stream short of the cut, drain ends after this long idle (s)",
              float_range=(0.001, 60.0)),
    ParamSpec("commit_period", 1.0, "seconds between storage commits (the most a SIGKILL loses)",
              float_range=(0.001, 3600.0)),
    ParamSpec("min_free_mb", 64.0, "free disk space (MB) needed to start; less while recording is "
              "warned once (0 = no check)", float_range=(0.0, 1e9)),
)
ABOUT = ("Record the sim topics to a rosbag2 (v9) without decoding; SIGINT/SIGTERM drain and close the bag.\n"
         "TOPIC ... sets 'topics', -o/--output sets 'output', -s/--storage sets 'storage'; use_sim_time "
         "(default False) stamps in sim time (/clock), keeping the publish order.")
RESERVE_BYTES = 2 * 1024 * 1024  # kept free beside the bag so that a full disk still lets it close


STREAM_PERIOD_S = 0.5  # a topic publishing at least every 0.5 s is a stream the drain waits for
PRECLOCK_LIMIT = 20_000  # under use_sim_time, messages held until the first /clock (then system time)


class RecorderError(OMPNError, ValueError):
    """A bad parameter or output path (one line, names the parameter or path)."""


def message_class(typename: str) -> Any:
    """rclpy message class of ``pkg/msg/Type`` (the same lookup rosidl_runtime_py does)."""
    pkg, kind, name = typename.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


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
class _Topic:
    name: str
    conn: Any
    stats: TopicStats
    sub: Any = None


class BagRecorder(Node):
    """Raw recorder of the sim topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = ParamTable(PARAMS).declare(self)
        storage = p["storage"]
        self.qos_depth = int(p["qos_depth"])
        self.gap_ns = int(float(p["gap_seconds"]) * 1e9)
        self.drain_timeout = float(p["drain_timeout"])
        self.drain_idle = float(p["drain_idle"])
        output = p["output"] or f"bags/rec_{dt.datetime.now(dt.UTC).strftime('%Y%m%d_%H%M%S')}"
        self.output = Path(output)
        if self.output.exists():
            raise RecorderError(f"output '{self.output}' already exists")
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self.wanted = {self.resolve_topic_name(t) for t in p["topics"]}
        step = _step_topic(self.resolve_topic_name(p["step_topic"]), self.wanted) if p["step_topic"] else None
        self.cut: StopCut[tuple[_Topic, int, bytes]] = StopCut(step)
        use_sim_time = bool(self.get_parameter("use_sim_time").value)
        self.sim_stamps = SimStamper() if use_sim_time else None
        self._preclock: list[tuple[_Topic, int, bytes]] = []
        self.write_errors = 0
        self.drain_seconds = 0.0
        self.drain_end = ""
        self.received_before_signal = 0
        self.commits: StepCommits[tuple[_Topic, int, bytes]] = StepCommits(step, float(p["commit_period"]))
        self.failed = ""  # the storage error that stopped the recording
        self.disk = DiskGuard(self.output, round(float(p["min_free_mb"]) * 1e6), RESERVE_BYTES)
        self.disk.start()  # NotEnoughSpace (an OSError: exit 2) before anything is created
        self._space_checked = time.monotonic()
        self.writer: DurableWriter | None = DurableWriter(
            self.output, version=9, storage_plugin=storage_plugin(storage), commit_period=None)
        try:
            self.writer.open()
        except BaseException:
            self.disk.release()
            raise
        self.topics: dict[str, _Topic] = {}
        self.qos = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
            history=HistoryPolicy.KEEP_ALL if self.qos_depth == 0 else HistoryPolicy.KEEP_LAST,
            depth=max(self.qos_depth, 1))
        self.get_logger().info(f"recording {sorted(self.wanted)} to {self.output} ({storage})")
        self._discover()
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # discovery must not wait for /clock
        self.create_timer(float(p["discovery_period"]), self._discover, clock=steady)

    @property
    def stats(self) -> dict[str, TopicStats]:
        return {name: t.stats for name, t in self.topics.items()}

    # --- discovery and intake ---------------------------------------------------------------------
    def _discover(self) -> None:
        if self.writer is None or self.cut.stopping:
            return
        for name, types in self.get_topic_names_and_types():
            if name not in self.wanted or name in self.topics:
                continue
            if len(types) != 1:
                self.get_logger().warning(f"topic {name} has several types {types}; not recorded")
                continue
            msgtype = types[0]
            if msgtype.startswith(f"{m.INTERFACES_PACKAGE}/"):  # ompn_node's typed outputs
                m.register_interfaces()
            if msgtype not in m.typestore().types:
                self.get_logger().warning(f"topic {name}: type {msgtype} unknown to the Jazzy typestore")
                continue
            offered = offered_qos(i.qos_profile for i in self.get_publishers_info_by_topic(name))
            conn = self.writer.add_connection(name, msgtype, typestore=m.typestore(),
                                              offered_qos_profiles=offered)
            topic = self.topics[name] = _Topic(name, conn, TopicStats(msgtype))
            topic.sub = self.create_subscription(message_class(msgtype), name,
                                                 self._callback(topic), self._qos_for(name), raw=True)
            self.get_logger().info(f"subscribed {name} [{msgtype}]")

    def _qos_for(self, name: str) -> QoSProfile:
        """Reliable, unless every publisher of ``name`` is best effort (a sensor driver): a reliable
        subscription would then never match, so take what they offer (as ``ros2 bag record`` does)."""
        infos = self.get_publishers_info_by_topic(name)
        if infos and all(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
            self.get_logger().info(f"{name}: best-effort publishers, recording best effort")
            return QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, durability=self.qos.durability,
                              history=self.qos.history, depth=self.qos.depth)
        return self.qos

    def _callback(self, topic: _Topic) -> Any:
        def on_message(raw: bytes, info: dict[str, Any]) -> None:
            self._on_message(topic, raw, info)

        return on_message

    def pump(self, limit: int = 5000) -> int:
        """Take up to ``limit`` queued messages straight from the subscriptions, handle them in
        source-stamp order (publish order across topics); returns how many."""
        batch: list[tuple[int, int, _Topic, bytes, dict[str, Any]]] = []
        for topic in list(self.topics.values()):
            sub = topic.sub
            while len(batch) < limit:
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, True)
                if got is None:
                    break
                raw, info = got
                batch.append((info.get("source_timestamp") or 0, len(batch), topic, raw, info))
        batch.sort(key=lambda item: item[:2])
        for _, _, topic, raw, info in batch:
            self._on_message(topic, raw, info)
        return len(batch)

    def _on_message(self, topic: _Topic, raw: bytes, info: dict[str, Any]) -> None:
        stats = topic.stats
        stats.received += 1
        src = info.get("source_timestamp") or 0
        if not src:
            src = info.get("received_timestamp") or time.time_ns()
            stats.receive_stamps += 1
        if self.cut.signal_ns is None or src < self.cut.signal_ns:
            self.received_before_signal += 1
        stats.taken(src)
        seq = info.get("publication_sequence_number")
        if seq is not None:
            if stats.last_seq is not None and seq > stats.last_seq + 1:
                stats.lost += seq - stats.last_seq - 1
            stats.last_seq = seq
        sim = self.sim_stamps
        if sim is not None and not sim.started:
            sim.open_step(src, self.get_clock().now().nanoseconds)
            if not sim.started and len(self._preclock) < PRECLOCK_LIMIT:
                self._preclock.append((topic, src, raw))  # stamped once /clock arrives
                return
            self._flush_preclock()
        self._offer(topic, src, raw)

    def _offer(self, topic: _Topic, src: int, raw: bytes) -> None:
        stamp = src
        sim = self.sim_stamps
        if sim is not None and sim.started:
            if topic.name == self.cut.step_topic or self.cut.step_topic is None:
                sim.open_step(src, self.get_clock().now().nanoseconds)
            stamp = sim.stamp(src)
        for item in self.cut.offer(topic.name, src, (topic, stamp, raw)):
            self._apply(self.commits.offer(topic.name, stamp, item, self._since_commit()))

    def _since_commit(self) -> float:
        return self.writer.since_checkpoint() if self.writer is not None else 0.0

    def _apply(self, actions: list[tuple[_Topic, int, bytes] | Any]) -> None:
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
        self.get_logger().error(self.failed)

    def _finish_held(self) -> None:
        """Write what the stop cut and the pending commit hold back (the recording ends)."""
        for item in self.cut.finish():
            self._apply(self.commits.offer(item[0].name, item[1], item, self._since_commit()))
        self._apply(self.commits.flush())

    def _flush_preclock(self) -> None:
        """Messages taken before the first ``/clock``: sim stamps if it came, else system time."""
        if self._preclock and (self.sim_stamps is None or not self.sim_stamps.started):
            self.get_logger().warning(f"use_sim_time: no /clock within {len(self._preclock)} messages; "
                                      "those are stamped in system time")
        pending, self._preclock = self._preclock, []
        for topic, src, raw in pending:
            self._offer(topic, src, raw)

    def _write(self, topic: _Topic, stamp: int, raw: bytes) -> None:
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

    def work(self) -> int | None:
        """After every wait: take what is queued, make the commits that are due; exit code 2 once the
        storage failed (the bag is then closed), else ``None``."""
        self.pump()
        self.tick()
        return 2 if self.failed else None

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
                self.get_logger().warning(low)

    # --- stop ---------------------------------------------------------------------------------------
    def drain(self, process: NodeProcess) -> None:
        """Take what DDS delivers until the streams reached the cut, or idle/timeout (module docstring)."""
        stop = process.stop
        assert stop.signal_ns is not None
        self.cut.request(stop.signal_ns)
        streams = {t.name: t for t in self.topics.values() if t.stats.streaming(stop.signal_ns)}
        start = last = time.monotonic()
        while True:
            before = sum(t.stats.count for t in self.topics.values())
            process.spin_once(0.01)
            self.pump()
            now = time.monotonic()
            if sum(t.stats.count for t in self.topics.values()) != before:
                last = now
            end = self._drain_over(streams, now - last, now - start, stop.signals)
            if end:
                self.drain_end = end
                break
        self._flush_preclock()
        self._finish_held()
        self.drain_seconds = time.monotonic() - start

    def _drain_over(self, streams: dict[str, _Topic], idle: float, elapsed: float, signals: int) -> str:
        """Why the drain ends now ('' = go on).

        Every topic that was streaming at the signal must deliver a message from the cut on (DDS
        delivers each writer's messages in order, so all before the cut are in); a stalled stream is
        waited for (a repaired DDS loss can take seconds) unless its publishers are gone.
        """
        if self.cut.cut_ns is not None and self.cut.passed >= set(streams):
            return "every streaming topic reached the cut"
        if idle >= self.drain_idle and all(t.sub.get_publisher_count() == 0 for t in streams.values()
                                           if t.name not in self.cut.passed):
            return f"nothing to write for {self.drain_idle:g} s and no stream left"
        if elapsed >= self.drain_timeout:
            return f"drain_timeout ({self.drain_timeout:g} s) reached"
        return "second signal" if signals > 1 else ""

    def close(self) -> str:
        """Close the bag; returns the summary text."""
        if self.writer is not None:
            if not self.failed:
                self._flush_preclock()
                self._finish_held()
            try:
                self.writer.close()
            except (OSError, sqlite3.Error) as err:  # even the reserve did not suffice
                self.failed = self.failed or f"cannot write to '{self.output}': {err}"
                self.get_logger().error(f"the bag could not be closed ({err}): read it with --on-error "
                                        "skip_tail (ompn_train: --set data.on_error=skip_tail)")
            self.writer = None
        self.disk.release()
        return self.summary()

    def summary(self) -> str:
        written = sum(s.count for s in self.stats.values())
        lines = [f"{NODE_NAME}: wrote {written} messages to {self.output}"]
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
        missing = sorted(self.wanted - set(self.topics))
        if missing:
            lines.append(f"  never seen: {missing}")
        if self.cut.stopping:
            received = sum(s.received for s in self.stats.values())
            lines.append(f"  stop: received {received} messages ({self.received_before_signal} published "
                         f"before the signal), drained {self.drain_seconds:.2f} s ({self.drain_end}), "
                         f"{self.cut.dropped} after the cut not recorded")
        if self.write_errors:
            lines.append(f"  {self.write_errors} messages could not be written")
        return "\n".join(lines)


def _step_topic(step: str, wanted: set[str]) -> str | None:
    """The recorded topic that opens a step: ``step`` itself, else the one recorded topic with its
    base name (topics recorded from another namespace), else ``None`` (stop at the signal)."""
    if step in wanted:
        return step
    same = [t for t in wanted if t.rsplit("/", 1)[-1] == step.rsplit("/", 1)[-1]]
    return same[0] if len(same) == 1 else None


def parse_cli(argv: list[str]) -> argparse.Namespace:
    """The recorder's own arguments (``-h``/``--help`` is left to :func:`ompn_ros.ros.run.run_node`)."""
    parser = argparse.ArgumentParser(prog=NODE_NAME, usage=f"{NODE_NAME} {USAGE}", add_help=False)
    parser.add_argument("-h", "--help", action="store_true")
    parser.add_argument("topics", nargs="*")
    parser.add_argument("-o", "--output")
    parser.add_argument("-s", "--storage", choices=STORAGES)
    return parser.parse_args(argv)


def _overrides(opts: argparse.Namespace) -> list[Parameter]:
    out = []
    if opts.topics:
        out.append(Parameter("topics", Parameter.Type.STRING_ARRAY, list(opts.topics)))
    if opts.output:
        out.append(Parameter("output", Parameter.Type.STRING, opts.output))
    if opts.storage:
        out.append(Parameter("storage", Parameter.Type.STRING, opts.storage))
    return out


def _serve(node: BagRecorder, process: NodeProcess) -> int:
    """Record until a signal (then drain) or a storage failure; the bag is closed and its summary
    printed however the recording ends."""
    try:
        code = process.serve(node.work, period=0.05)
        if process.stop.signal_ns is not None and not node.failed:
            node.drain(process)
    finally:
        print(node.close(), flush=True)
    return 2 if node.failed else code


def main(args: list[str] | None = None) -> int:
    """Console script ``bag_recorder``: exit 0 after SIGINT/SIGTERM (the bag drained and closed), 2 on a
    bad parameter, output or too little space (one line), or when the storage failed while recording."""
    argv = list(sys.argv if args is None else args)
    opts = parse_cli(remove_ros_args(argv)[1:])  # bad flags exit 2 here, before any side effect
    return run_node(NODE_NAME, lambda: BagRecorder(parameter_overrides=_overrides(opts)), argv,
                    about=ABOUT, params=PARAMS, usage=USAGE, serve=_serve, errors=(RecorderError, OSError),
                    label="error: ")


if __name__ == "__main__":
    sys.exit(main())
