"""``bag_recorder``: record the sim topics to a rosbag2 (v9, mcap or sqlite3) without decoding.

Parameters:
    topics (string[]): topics to record; relative names resolve in the node's namespace.
        Default: every topic the sims publish (``ompn_ros.layout``).
    output (string): bag directory to create; default ``bags/rec_<UTC timestamp>``.
    storage (string): ``mcap`` (default) or ``sqlite3``.
    qos_depth (int): KEEP_LAST depth of the RELIABLE subscriptions (default 1000: at the sims'
        25-100 Hz a stall of 10 s loses nothing).
    discovery_period (double): seconds between topic discovery passes (default 0.2).
    gap_seconds (double): a per-topic stamp jump larger than this is reported as a time gap.

Subscriptions are ``raw=True`` (CDR bytes go to the bag untouched), RELIABLE + VOLATILE (compatible
with both volatile and transient-local publishers).  Topics are subscribed as they appear
(``get_topic_names_and_types``), each with its discovered type.

**Stamps:** every message is written at the publisher's ``source_timestamp`` from the message info
that rclpy 7.1.6 passes to a two-argument subscription callback (falling back to
``received_timestamp`` if a middleware gives none).  Source stamps keep the publish order of the
step contract across topics, whatever the delivery order.  Loss is detected from
``publication_sequence_number`` jumps per topic (a backwards jump = another publisher, not counted).

Stops cleanly on SIGINT/SIGTERM: closes the bag and prints a summary (messages per topic, sequence
jumps, large time gaps).
"""

from __future__ import annotations

import datetime as dt
import importlib
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.bag_writer import STORAGES, storage_plugin

DEFAULT_TOPICS = [
    layout.EPISODE, layout.SKETCH, layout.OBSERVATION, layout.JOINT_STATES, layout.SUBTASK,
    layout.ACTION, layout.RENDER,
]


def message_class(typename: str) -> Any:
    """rclpy message class of ``pkg/msg/Type`` (the same lookup rosidl_runtime_py does)."""
    pkg, kind, name = typename.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


@dataclass
class TopicStats:
    """Per-topic recording statistics."""

    msgtype: str
    count: int = 0
    last_seq: int | None = None
    lost: int = 0  # messages missing according to publication sequence numbers
    last_stamp: int | None = None
    time_gaps: list[float] = field(default_factory=list)
    receive_stamps: int = 0  # messages written at receive time (no source timestamp)


class BagRecorder(Node):
    """Raw recorder of the sim topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("bag_recorder", **kwargs)
        topics = self.declare_parameter("topics", DEFAULT_TOPICS).value
        output = self.declare_parameter("output", "").value
        storage = self.declare_parameter("storage", "mcap").value
        self.qos_depth = int(self.declare_parameter("qos_depth", 1000).value)
        period = float(self.declare_parameter("discovery_period", 0.2).value)
        self.gap_ns = int(float(self.declare_parameter("gap_seconds", 0.5).value) * 1e9)
        if storage not in STORAGES:
            raise ValueError(f"parameter storage='{storage}' must be one of {STORAGES}")
        if not output:
            output = f"bags/rec_{dt.datetime.now(dt.UTC).strftime('%Y%m%d_%H%M%S')}"
        self.output = Path(output)
        if self.output.exists():
            raise FileExistsError(f"bag_recorder: output '{self.output}' already exists")
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self.wanted = {self.resolve_topic_name(t) for t in topics}
        from rosbags.rosbag2 import Writer

        self.writer: Any = Writer(self.output, version=9, storage_plugin=storage_plugin(storage))
        self.writer.open()
        self.stats: dict[str, TopicStats] = {}
        self._subs: list[Any] = []
        self.qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                              depth=self.qos_depth, durability=DurabilityPolicy.VOLATILE)
        self.get_logger().info(f"recording {sorted(self.wanted)} to {self.output} ({storage})")
        self._discover()
        self.create_timer(period, self._discover)

    def _discover(self) -> None:
        for name, types in self.get_topic_names_and_types():
            if name not in self.wanted or name in self.stats:
                continue
            if len(types) != 1:
                self.get_logger().warning(f"topic {name} has several types {types}; not recorded")
                continue
            msgtype = types[0]
            if msgtype not in m.typestore().types:
                self.get_logger().warning(f"topic {name}: type {msgtype} unknown to the Jazzy typestore")
                continue
            conn = self.writer.add_connection(name, msgtype, typestore=m.typestore())
            self.stats[name] = stats = TopicStats(msgtype)
            self._subs.append(self.create_subscription(
                message_class(msgtype), name, self._callback(conn, stats), self.qos, raw=True))
            self.get_logger().info(f"subscribed {name} [{msgtype}]")

    def _callback(self, conn: Any, stats: TopicStats) -> Any:
        writer = self.writer
        gap_ns = self.gap_ns

        def on_message(raw: bytes, info: dict[str, Any]) -> None:
            stamp = info.get("source_timestamp") or 0
            if not stamp:
                stamp = info.get("received_timestamp") or self.get_clock().now().nanoseconds
                stats.receive_stamps += 1
            writer.write(conn, stamp, raw)
            stats.count += 1
            seq = info.get("publication_sequence_number")
            if seq is not None:
                if stats.last_seq is not None and seq > stats.last_seq + 1:
                    stats.lost += seq - stats.last_seq - 1
                stats.last_seq = seq
            if stats.last_stamp is not None and stamp - stats.last_stamp > gap_ns:
                stats.time_gaps.append((stamp - stats.last_stamp) / 1e9)
            stats.last_stamp = stamp

        return on_message

    def close(self) -> str:
        """Close the bag; returns the summary text."""
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        return self.summary()

    def summary(self) -> str:
        lines = [f"bag_recorder: wrote {sum(s.count for s in self.stats.values())} messages to {self.output}"]
        for name in sorted(self.stats):
            s = self.stats[name]
            line = f"  {name} [{s.msgtype}]: {s.count} messages"
            if s.lost:
                line += f", {s.lost} lost (sequence jumps)"
            if s.time_gaps:
                line += (f", {len(s.time_gaps)} time gap(s) > {self.gap_ns / 1e9:g} s "
                         f"(max {max(s.time_gaps):.2f} s)")
            if s.receive_stamps:
                line += f", {s.receive_stamps} stamped at receive time"
            lines.append(line)
        missing = sorted(self.wanted - set(self.stats))
        if missing:
            lines.append(f"  never seen: {missing}")
        return "\n".join(lines)


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = BagRecorder()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (FileExistsError, ValueError) as err:
        print(f"bag_recorder: error: {err}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    finally:
        if node is not None:
            print(node.close(), flush=True)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
