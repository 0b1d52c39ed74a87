"""A node started as a process by a test, and the test's side of the graph it joins.

:class:`NodeProcess` starts ``ompn_node`` (or another node module) with the environment of the
``ros_env`` fixture (DDS containment, ``LD_LIBRARY_PATH`` kept) and stops it cleanly: SIGINT, a kill
after a time-out, and its whole output (stdout and stderr in order) kept for the failure message.
:class:`Peer` is this process's side: one rclpy node in a context of its own that records the
``/diagnostics`` statuses of every node, spins until a condition holds while failing at once, with
the output, when a watched node process dies, and waits until a node is active (its first status: the
node starts its ``/diagnostics`` timer when it activates).  Episode markers: :mod:`episode_markers`.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ompn_ros.ros import containment

ROOT = Path(__file__).resolve().parents[1]
OMPN_NODE = "ompn_ros.nodes.ompn_node"


def node_command(*params: str, module: str = OMPN_NODE, ns: str | None = None,
                 program: list[str] | None = None) -> list[str]:
    """The command line of a node: ``python -m module`` (or ``program``: a script, ``-c`` code and its
    arguments), then ``params`` as ``-p name:=value`` and namespace ``ns`` (``"/robot"``) as ROS
    arguments, when there are any."""
    command = list(program) if program is not None else [sys.executable, "-m", module]
    ros_args = [] if ns is None else ["-r", f"__ns:={ns}"]
    for param in params:
        ros_args += ["-p", param]
    return [*command, "--ros-args", *ros_args] if ros_args or program is None else command


def check_environment(env: dict[str, str]) -> None:
    """Fail unless ``env`` is contained (:mod:`ompn_ros.ros.containment`) and keeps this process's
    ``LD_LIBRARY_PATH`` (without it the child cannot load the ROS libraries)."""
    problems = containment.problems(env)
    assert not problems, f"the node's environment is not contained (use the ros_env fixture): {problems}"
    ours = os.environ.get("LD_LIBRARY_PATH", "")
    assert ours in env.get("LD_LIBRARY_PATH", ""), "the node's environment dropped LD_LIBRARY_PATH"


class NodeProcess:
    """One node process, started at construction; :meth:`stop` (or leaving a ``with`` block) ends it.

    Args:
        env: the child's environment: the ``ros_env`` fixture's (or one built from it).
        params: ``name:=value`` parameters.
        module: the node's module (``python -m``).
        ns: its namespace (``"/robot"``); None: the default.
        cwd: its working directory (the repository root unless given).
        program: what runs instead of ``python -m module``: ``[sys.executable, script]``, or
            ``[sys.executable, "-c", code, *args]`` (a driver or a sim the test writes).
        stdin: give it a standard input the test writes to (:meth:`send`).
    """

    def __init__(self, env: dict[str, str], *params: str, module: str = OMPN_NODE, ns: str | None = None,
                 cwd: Path | str = ROOT, program: list[str] | None = None, stdin: bool = False) -> None:
        check_environment(env)
        self.name = module if program is None else " ".join(program[1:2])  # the module, script or "-c"
        self.ns = ns
        self.command = node_command(*params, module=module, ns=ns, program=program)
        self.proc = subprocess.Popen(self.command, env=env, cwd=str(cwd), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, stdin=subprocess.PIPE if stdin else None,
                                     text=True)  # fmt: skip
        self._output: str | None = None

    def topic(self, name: str) -> str:
        """``name`` in the node's namespace (``"ompn_node/pi"`` -> ``"/robot/ompn_node/pi"``)."""
        return f"{(self.ns or '').rstrip('/')}/{name}"

    @property
    def status_name(self) -> str:
        """The name of ``ompn_node``'s status on ``/diagnostics`` (``"/robot/ompn_node: segmenter"``)."""
        return f"{self.topic('ompn_node')}: segmenter"

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def running(self) -> bool:
        return self.proc.poll() is None

    def wait(self, timeout: float) -> int:
        """Wait up to ``timeout`` s for it to end by itself (``subprocess.TimeoutExpired`` if it does not);
        its exit status."""
        return self.proc.wait(timeout=timeout)

    def send(self, line: str) -> None:
        """Write ``line`` to its standard input (made with ``stdin=True``)."""
        assert self.proc.stdin is not None, "started without stdin=True"
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def check(self) -> None:
        """Fail with the node's output if it is no longer running."""
        if not self.running():
            raise AssertionError(f"{self.name} exited ({self.proc.returncode}): {self.stop()}")

    def stop(self, timeout: float = 15.0) -> str:
        """SIGINT if it still runs, up to ``timeout`` s for it to end (then kill); its whole output.  Once
        stopped, the same output again."""
        if self._output is None:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGINT)
            try:
                self._output = self.proc.communicate(timeout=timeout)[0]
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self._output = self.proc.communicate()[0]
        return self._output

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class Peer:
    """This process's side of the graph: a node ``name`` in its own rclpy context with one executor, the
    ``/diagnostics`` statuses it received (by status name) and the node processes it watches."""

    def __init__(self, *watched: NodeProcess, name: str = "test_peer") -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.node: Any = rclpy.create_node(name, context=self.ctx)  # callbacks typed by each test
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.watched = list(watched)
        self._values: dict[str, list[dict[str, str]]] = {}
        self._stamps: dict[str, list[int]] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 100)

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            self.statuses(status.name).append({kv.key: kv.value for kv in status.values})
            self.stamps(status.name).append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

    def statuses(self, name: str) -> list[dict[str, str]]:
        """The values of every status ``name`` received so far, oldest first (a live list)."""
        return self._values.setdefault(name, [])

    def stamps(self, name: str) -> list[int]:
        """The header stamps of the arrays that carried them (a live list, beside :meth:`statuses`)."""
        return self._stamps.setdefault(name, [])

    def last(self, name: str) -> dict[str, str]:
        """The values of the last status ``name`` received; empty before the first."""
        values = self.statuses(name)
        return values[-1] if values else {}

    def pump(self, until: Callable[..., bool], timeout: float, watch: bool = True) -> bool:
        """Spin until ``until()`` holds or ``timeout`` s passed; whether it holds.  With ``watch``, a
        watched process that died fails the test at once, with its output."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.ex.spin_once(timeout_sec=0.01)
            if until():
                return True
            if watch:
                for proc in self.watched:
                    proc.check()
        return bool(until())

    def wait_active(self, proc: NodeProcess, timeout: float = 60.0) -> None:
        """Wait until ``ompn_node`` of ``proc`` is active: its first status on ``/diagnostics``."""
        assert self.pump(lambda: bool(self.statuses(proc.status_name)), timeout), (
            f"{proc.status_name} never appeared on /diagnostics within {timeout} s: {proc.stop()}")

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown(context=self.ctx)

    def __enter__(self) -> Peer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

