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
import sys
import time
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import STORAGES
from ompn_ros.data.recorder.recording import RecordedTopic, Recording
from ompn_ros.data.recorder.sim_stamps import SimStamper
from ompn_ros.data.recorder.storage import offered_qos
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
PRECLOCK_LIMIT = 20_000  # under use_sim_time, messages held until the first /clock (then system time)


class RecorderError(OMPNError, ValueError):
    """A bad parameter or output path (one line, names the parameter or path)."""


def message_class(typename: str) -> Any:
    """rclpy message class of ``pkg/msg/Type`` (the same lookup rosidl_runtime_py does)."""
    pkg, kind, name = typename.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


class BagRecorder(Node):
    """Raw recorder of the sim topics (see the module docstring): the subscriptions, the stamps and
    the drain; the bag itself is its :class:`~ompn_ros.data.recorder.recording.Recording`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = ParamTable(PARAMS).declare(self)
        storage = p["storage"]
        self.qos_depth = int(p["qos_depth"])
        self.drain_timeout = float(p["drain_timeout"])
        self.drain_idle = float(p["drain_idle"])
        output = p["output"] or f"bags/rec_{dt.datetime.now(dt.UTC).strftime('%Y%m%d_%H%M%S')}"
        self.output = Path(output)
        if self.output.exists():
            raise RecorderError(f"output '{self.output}' already exists")
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self.wanted = {self.resolve_topic_name(t) for t in p["topics"]}
        step = _step_topic(self.resolve_topic_name(p["step_topic"]), self.wanted) if p["step_topic"] else None
        use_sim_time = bool(self.get_parameter("use_sim_time").value)
        self.sim_stamps = SimStamper() if use_sim_time else None
        self._preclock: list[tuple[RecordedTopic, int, bytes]] = []
        self.drain_seconds = 0.0
        self.drain_end = ""
        self.received_before_signal = 0
        self.recording = Recording(self.output, storage, step, float(p["commit_period"]),
                                   round(float(p["min_free_mb"]) * 1e6), int(float(p["gap_seconds"]) * 1e9),
                                   self.get_logger())
        self.subscriptions_by_topic: dict[str, Any] = {}
        self.qos = QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
            history=HistoryPolicy.KEEP_ALL if self.qos_depth == 0 else HistoryPolicy.KEEP_LAST,
            depth=max(self.qos_depth, 1))
        self.get_logger().info(f"recording {sorted(self.wanted)} to {self.output} ({storage})")
        self._discover()
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # discovery must not wait for /clock
        self.create_timer(float(p["discovery_period"]), self._discover, clock=steady)

    @property
    def failed(self) -> str:
        """The storage error that stopped the recording ('' = none)."""
        return self.recording.failed

    # --- discovery and intake ---------------------------------------------------------------------
    def _discover(self) -> None:
        rec = self.recording
        if rec.writer is None or rec.cut.stopping:
            return
        for name, types in self.get_topic_names_and_types():
            if name not in self.wanted or name in rec.topics:
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
            topic = rec.add_topic(name, msgtype, offered)
            self.subscriptions_by_topic[name] = self.create_subscription(
                message_class(msgtype), name, self._callback(topic), self._qos_for(name), raw=True)
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

    def _callback(self, topic: RecordedTopic) -> Any:
        def on_message(raw: bytes, info: dict[str, Any]) -> None:
            self._on_message(topic, raw, info)

        return on_message

    def pump(self, limit: int = 5000) -> int:
        """Take up to ``limit`` queued messages straight from the subscriptions, handle them in
        source-stamp order (publish order across topics); returns how many."""
        batch: list[tuple[int, int, RecordedTopic, bytes, dict[str, Any]]] = []
        for name, sub in list(self.subscriptions_by_topic.items()):
            topic = self.recording.topics[name]
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

    def _on_message(self, topic: RecordedTopic, raw: bytes, info: dict[str, Any]) -> None:
        stats = topic.stats
        stats.received += 1
        src = info.get("source_timestamp") or 0
        if not src:
            src = info.get("received_timestamp") or time.time_ns()
            stats.receive_stamps += 1
        signal_ns = self.recording.cut.signal_ns
        if signal_ns is None or src < signal_ns:
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

    def _offer(self, topic: RecordedTopic, src: int, raw: bytes) -> None:
        stamp = src
        sim = self.sim_stamps
        if sim is not None and sim.started:
            step_topic = self.recording.cut.step_topic
            if topic.name == step_topic or step_topic is None:
                sim.open_step(src, self.get_clock().now().nanoseconds)
            stamp = sim.stamp(src)
        self.recording.offer(topic, src, stamp, raw)

    def _flush_preclock(self) -> None:
        """Messages taken before the first ``/clock``: sim stamps if it came, else system time."""
        if self._preclock and (self.sim_stamps is None or not self.sim_stamps.started):
            self.get_logger().warning(f"use_sim_time: no /clock within {len(self._preclock)} messages; "
                                      "those are stamped in system time")
        pending, self._preclock = self._preclock, []
        for topic, src, raw in pending:
            self._offer(topic, src, raw)

    def work(self) -> int | None:
        """After every wait: take what is queued, make the commits that are due; exit code 2 once the
        storage failed (the bag is then closed), else ``None``."""
        self.pump()
        self.recording.tick()
        return 2 if self.failed else None

    # --- stop ---------------------------------------------------------------------------------------
    def drain(self, process: NodeProcess) -> None:
        """Take what DDS delivers until the streams reached the cut, or idle/timeout (module docstring)."""
        stop = process.stop
        assert stop.signal_ns is not None
        topics = self.recording.topics
        self.recording.cut.request(stop.signal_ns)
        streams = {t.name: t for t in topics.values() if t.stats.streaming(stop.signal_ns)}
        start = last = time.monotonic()
        while True:
            before = sum(t.stats.count for t in topics.values())
            process.spin_once(0.01)
            self.pump()
            now = time.monotonic()
            if sum(t.stats.count for t in topics.values()) != before:
                last = now
            end = self._drain_over(streams, now - last, now - start, stop.signals)
            if end:
                self.drain_end = end
                break
        self._flush_preclock()
        self.recording.finish()
        self.drain_seconds = time.monotonic() - start

    def _drain_over(self, streams: dict[str, RecordedTopic], idle: float, elapsed: float,
                    signals: int) -> str:
        """Why the drain ends now ('' = go on).

        Every topic that was streaming at the signal must deliver a message from the cut on (DDS
        delivers each writer's messages in order, so all before the cut are in); a stalled stream is
        waited for (a repaired DDS loss can take seconds) unless its publishers are gone.
        """
        cut, subs = self.recording.cut, self.subscriptions_by_topic
        if cut.cut_ns is not None and cut.passed >= set(streams):
            return "every streaming topic reached the cut"
        if idle >= self.drain_idle and all(subs[name].get_publisher_count() == 0 for name in streams
                                           if name not in cut.passed):
            return f"nothing to write for {self.drain_idle:g} s and no stream left"
        if elapsed >= self.drain_timeout:
            return f"drain_timeout ({self.drain_timeout:g} s) reached"
        return "second signal" if signals > 1 else ""

    def close(self) -> str:
        """Close the bag; returns the summary text."""
        rec = self.recording
        if rec.writer is not None and not rec.failed:
            self._flush_preclock()
            rec.finish()
        rec.close()
        return self.summary()

    def summary(self) -> str:
        rec = self.recording
        written = sum(t.stats.count for t in rec.topics.values())
        lines = [f"{NODE_NAME}: wrote {written} messages to {self.output}", *rec.topic_lines()]
        missing = sorted(self.wanted - set(rec.topics))
        if missing:
            lines.append(f"  never seen: {missing}")
        if rec.cut.stopping:
            received = sum(t.stats.received for t in rec.topics.values())
            lines.append(f"  stop: received {received} messages ({self.received_before_signal} published "
                         f"before the signal), drained {self.drain_seconds:.2f} s ({self.drain_end}), "
                         f"{rec.cut.dropped} after the cut not recorded")
        if rec.write_errors:
            lines.append(f"  {rec.write_errors} messages could not be written")
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
