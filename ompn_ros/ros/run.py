"""One way to run a node as a process: the ``main()`` of every node of this package and of both sims.

:func:`run_node` is the whole of a node's ``main()``, in this order:

1. ``-h``/``--help`` before ``--ros-args`` prints the node's parameters
   (:func:`ompn_ros.ros.params.help_text`) and exits 0 before anything touches ROS or the disk;
2. SIGINT and SIGTERM set the process's :class:`StopRequest` (rclpy's own handlers stay out: they shut
   the context down while a callback, e.g. a diagnostics timer, may be running, which then fails with
   a FATAL line).  The serving loop ends at its next wait, then the executor, the node and the context
   are shut down, in that order.  A signal ends the process with exit code 0, unless the node's serve
   function returns another code (it may finish its work first: the recorder drains and closes its bag);
3. ``rclpy.init`` with the command line: ROS arguments rcl cannot parse are one line and exit code 2;
4. the node is built: a known start error (:class:`~ompn_ros.ros.params.ParameterError` and the
   node's own ``errors``) is one line ``<prog>: <reason>`` and exit code 2; anything else is a bug and
   keeps its traceback;
5. the node is served on one executor (``'single'``: ``SingleThreadedExecutor``; ``'events'``:
   ``rclpy.experimental.EventsExecutor``, ``ompn_node``'s default) by its serve function, which
   returns the exit code.

**How a node ends its process** (the one stop policy): :meth:`NodeProcess.serve` serves callbacks and,
after every wait, asks the node's ``poll``; ``None`` goes on, an exit code ends the process with it
(``ompn_node``'s shutdown transition: 0; the recorder's full disk: 2; the sims' last episode: 0;
``episode_monitor``'s timeout: 3).  A signal ends the loop as well.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from types import FrameType
from typing import Any, TypeVar

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ompn_ros.ros.params import ParameterError, ParamSpec, help_text, wants_help

N = TypeVar("N", bound=Node)
Poll = Callable[[], int | None]


def make_executor(kind: str, context: Any = None) -> Any:
    """``'events'``: the C++ ``rclpy.experimental.EventsExecutor`` (not an rclpy ``Executor`` subclass);
    ``'single'``: SingleThreadedExecutor.

    Only ``spin_once`` is used on either: the EventsExecutor's ``spin()`` in rclpy 7.1.6 serves no
    callback and ignores SIGINT, while its ``spin_once`` works.
    """
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


class StopRequest(threading.Event):
    """Set by SIGINT/SIGTERM once :meth:`install` ran: the system time of the first signal and how many
    came (a second one cuts the recorder's drain short)."""

    def __init__(self) -> None:
        super().__init__()
        self.signal_ns: int | None = None
        self.signals = 0

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.signal_ns is None:
            self.signal_ns = time.time_ns()
        self.signals += 1
        self.set()

    def install(self) -> None:
        """Handle SIGINT and SIGTERM with this request (instead of Python's and rclpy's handlers)."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self)


def _go_on() -> int | None:
    return None


@dataclass
class NodeProcess:
    """The executor serving a node and the process's stop request, handed to the node's serve function."""

    executor: Any  # an rclpy Executor or the EventsExecutor (make_executor)
    stop: StopRequest

    def running(self) -> bool:
        """No signal came and the context is up."""
        return not self.stop.is_set() and rclpy.ok(context=self.executor.context)

    def spin_once(self, timeout: float) -> None:
        """Serve ready callbacks, waiting up to ``timeout`` seconds for one."""
        self.executor.spin_once(timeout_sec=timeout)

    def serve(self, poll: Poll = _go_on, period: float = 0.1) -> int:
        """Serve callbacks until a signal (exit code 0) or until ``poll``, asked after every wait of up to
        ``period`` seconds, returns an exit code."""
        while self.running():
            self.spin_once(period)
            code = poll()
            if code is not None:
                return code
        return 0

    def linger(self, seconds: float, period: float = 0.05) -> None:
        """Go on serving for ``seconds`` (reliable messages still in flight get delivered), unless a signal
        comes."""
        deadline = time.monotonic() + seconds
        while self.running() and time.monotonic() < deadline:
            self.spin_once(period)


def serve_until_stopped(node: Node, process: NodeProcess) -> int:
    """The serve function of a node that runs until a signal."""
    return process.serve()


def run_node(prog: str, build: Callable[[], N], args: list[str] | None, *, about: str,
             params: Iterable[ParamSpec], serve: Callable[[N, NodeProcess], int] = serve_until_stopped,
             executor: str | Callable[[N], str] = "single", errors: tuple[type[Exception], ...] = (),
             label: str = "", usage: str = "") -> int:
    """The ``main()`` of a node (module docstring): returns its exit code.

    ``build`` makes the node after ``rclpy.init``; ``serve`` runs it (default: until a signal);
    ``executor`` is the executor's kind or reads it from the node; ``errors`` are the node's known
    start errors besides :class:`ParameterError`, printed as ``<prog>: <label><reason>``; ``usage``
    adds the node's own arguments to the ``--help`` usage line.
    """
    if wants_help(args):
        print(help_text(prog, about, params, usage=usage))
        return 0
    stop = StopRequest()
    stop.install()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rcl rejects the command line (RCLError): one line, no traceback
        print(f"{prog}: invalid ROS arguments: {str(exc).split(', at ')[0]}", file=sys.stderr)
        return 2
    known: tuple[type[Exception], ...] = (ParameterError, *errors)
    node: N | None = None
    ex: Any = None
    try:
        try:
            node = build()
        except known as exc:
            print(f"{prog}: {label}{exc}", file=sys.stderr, flush=True)
            return 2
        ex = make_executor(executor if isinstance(executor, str) else executor(node))
        ex.add_node(node)
        return serve(node, NodeProcess(ex, stop))
    except ExternalShutdownException:  # the context was shut down under a wait
        return 0
    finally:
        if ex is not None:
            ex.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
