"""A sim started as a process and a listener of its topics (QoS, stamps), for the sim tests."""

from __future__ import annotations

import subprocess
import time
import uuid
from collections.abc import Callable

import pytest

rclpy = pytest.importorskip("rclpy")
from node_process import check_environment, node_command  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def stamp_ns(stamp: object) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)  # type: ignore[attr-defined]


class Listener:
    """A test-side node in its own context: subscribes to named topics and logs (topic, msg, source stamp)."""

    def __init__(self) -> None:
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(f"sim_test_{uuid.uuid4().hex[:6]}", context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.log: list[tuple[str, object, int]] = []

    def listen(self, topic: str, msg_type: type, qos: QoSProfile) -> None:
        def on_message(msg: object, info: dict, t: str = topic) -> None:
            self.log.append((t, msg, int(info["source_timestamp"])))

        self.node.create_subscription(msg_type, topic, on_message, qos)

    def of(self, topic: str) -> list:
        return [m for t, m, _ in self.log if t == topic]

    def spin_until(self, done: Callable[[], bool], timeout: float) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not done():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def launch(env: dict[str, str], namespace: str, *params: str, sim: str = "dial") -> subprocess.Popen:
    """The sim node ``sim`` in namespace ``/namespace``, run to its end (:func:`finish`), stderr apart."""
    check_environment(env)
    args = node_command(*params, module=f"sim_nodes.{sim}.node", ns=f"/{namespace}")
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen, timeout: float = 30) -> tuple[int | None, str]:
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return proc.returncode, err
