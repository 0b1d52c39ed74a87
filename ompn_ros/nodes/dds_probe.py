"""DDS self-check: a talker and a listener that measure delivery and latency between two processes.

``smoke_talker`` publishes ``count`` stamped messages on ``smoke`` at ``rate`` Hz, waits until every
matched subscriber has acknowledged them (``ack_timeout``), prints a one-line JSON summary (published,
matched subscribers, acked) and exits.
``smoke_listener`` counts what it receives, prints a one-line JSON summary (received, lost,
latency percentiles) and exits after ``count`` messages or ``timeout`` seconds of silence.
Both run under ``ros2 run ompn_ros smoke_talker`` and accept ``--ros-args --params-file``; an invalid
parameter ends them with one line naming it and exit code 2.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable

import rclpy
from rclpy.duration import Duration
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from ompn_ros.ros.params import ParamSpec, ParamTable
from ompn_ros.ros.run import NodeProcess, run_node

TOPIC = "smoke"
QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
COMMON = (
    ParamSpec("count", 50, "number of messages to exchange", int_range=(1, 1_000_000)),
    ParamSpec("rate", 50.0, "publish rate in Hz", float_range=(0.1, 10_000.0)),
)
TALKER_PARAMS = ParamTable((
    *COMMON,
    ParamSpec("wait_for_subscriber", 5.0, "seconds to wait for a subscriber before publishing",
              float_range=(0.0, 3600.0)),
    ParamSpec("ack_timeout", 10.0, "seconds to wait, after the last message, for every matched "
              "subscriber to acknowledge all of them", float_range=(0.0, 3600.0)),
))  # fmt: skip
LISTENER_PARAMS = ParamTable((
    *COMMON,
    ParamSpec("timeout", 10.0, "seconds of silence after which the listener gives up",
              float_range=(0.1, 3600.0)),
))  # fmt: skip


class SmokeTalker(Node):
    """Publishes ``count`` JointState messages whose position[0] is the sequence number."""

    def __init__(self) -> None:
        super().__init__("smoke_talker")
        self.values = TALKER_PARAMS.declare(self)  # ParameterError on an invalid value
        self.count = int(self.values["count"])
        self.period = 1.0 / float(self.values["rate"])
        self.publisher = self.create_publisher(JointState, TOPIC, QOS)
        self.sent = 0
        self.acked = False
        self.matched = 0

    def run(self, live: Callable[[], bool] = rclpy.ok) -> int:
        """Wait for a subscriber, publish, wait for the acks, while ``live()`` (the context is up; under
        :func:`talker_main`: and no signal came); the summary line is printed however the run ends.
        Exit code 0."""
        try:
            deadline = time.monotonic() + float(self.values["wait_for_subscriber"])
            while self.publisher.get_subscription_count() == 0 and time.monotonic() < deadline and live():
                time.sleep(0.05)
            self.matched = self.publisher.get_subscription_count()
            self._publish_all(live)
            # A subscriber the talker has matched may not have matched the talker yet (discovery is
            # not symmetric, and slow under load): the writer must outlive its samples' delivery.
            ack_timeout = Duration(seconds=float(self.values["ack_timeout"]))
            self.acked = live() and self.publisher.wait_for_all_acked(ack_timeout)
        except _rclpy.RCLError:
            if rclpy.ok():
                raise
        finally:
            summary = {"published": self.sent, "matched": self.matched, "acked": self.acked}
            print(json.dumps({**summary, "topic": self.publisher.topic_name}), flush=True)
        return 0

    def _publish_all(self, live: Callable[[], bool]) -> None:
        """Publish ``count`` messages at ``rate`` Hz, or until ``live()`` turns false."""
        next_due = time.monotonic()
        while self.sent < self.count and live():
            msg = JointState()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.name = ["seq"]
            msg.position = [float(self.sent)]
            self.publisher.publish(msg)
            self.sent += 1
            next_due += self.period
            time.sleep(max(0.0, next_due - time.monotonic()))


class SmokeListener(Node):
    """Counts messages and latencies; ``summary()`` returns the result."""

    def __init__(self) -> None:
        super().__init__("smoke_listener")
        self.values = LISTENER_PARAMS.declare(self)  # ParameterError on an invalid value
        self.count = int(self.values["count"])
        self.timeout = float(self.values["timeout"])
        self.seen: set[int] = set()
        self.latencies_ms: list[float] = []
        self._received = 0  # messages seen at the last progress
        self._last_progress = time.monotonic()
        self.create_subscription(JointState, TOPIC, self._on_message, QOS)

    def _on_message(self, msg: JointState) -> None:
        now = self.get_clock().now().nanoseconds
        sent = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.latencies_ms.append((now - sent) / 1e6)
        self.seen.add(int(msg.position[0]))

    def poll(self) -> int | None:
        """After every wait: once ``count`` messages arrived or ``timeout`` seconds passed without a new
        one, print the summary and return the exit code (0: none lost, 1: some lost), else ``None``."""
        now = time.monotonic()
        if len(self.seen) != self._received:
            self._received = len(self.seen)
            self._last_progress = now
        elif now - self._last_progress > self.timeout:
            return self._finish()
        return self._finish() if len(self.seen) >= self.count else None

    def _finish(self) -> int:
        result = self.summary()
        print(json.dumps(result), flush=True)
        return 0 if result["lost"] == 0 else 1

    def summary(self) -> dict:
        lat = sorted(self.latencies_ms)

        def pct(q: float) -> float:
            return round(lat[min(len(lat) - 1, int(q * len(lat)))], 3) if lat else float("nan")

        return {
            "expected": self.count,
            "received": len(self.seen),
            "lost": self.count - len(self.seen),
            "latency_ms_p50": pct(0.5),
            "latency_ms_p99": pct(0.99),
        }


ABOUT = "DDS self-check: a talker and a listener count what arrives."


def talker_main(args: list[str] | None = None) -> None:
    """Console script ``smoke_talker``: exit 0, 2 on an invalid parameter (one line)."""
    sys.exit(run_node("smoke_talker", SmokeTalker, args, about=ABOUT, params=TALKER_PARAMS.specs.values(),
                      serve=lambda node, process: node.run(process.running)))


def _serve_listener(node: SmokeListener, process: NodeProcess) -> int:
    return process.serve(node.poll)


def listener_main(args: list[str] | None = None) -> None:
    """Console script ``smoke_listener``: exit 0 (all delivered), 1 (messages lost), 2 (invalid parameter,
    one line)."""
    sys.exit(run_node("smoke_listener", SmokeListener, args, about=ABOUT,
                      params=LISTENER_PARAMS.specs.values(), serve=_serve_listener))


if __name__ == "__main__":
    role = sys.argv[1] if len(sys.argv) > 1 and sys.argv[1] in ("talker", "listener") else "talker"
    rest = [sys.argv[0], *sys.argv[2:]] if len(sys.argv) > 1 and sys.argv[1] == role else sys.argv
    (talker_main if role == "talker" else listener_main)(rest)
