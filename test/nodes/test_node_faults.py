"""ompn_node in process under a careless user: marker floods, contradicting detector parameters, clocks
that go negative, stall or jump, and a second node with the same name (DDS on loopback)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from episode_markers import marker  # noqa: E402
from node_process import NodeProcess  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.nodes import ompn_node_inputs  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402

OBS_DIM = 4
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "faults", seed=6,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=2, slot_size=8)


def make_node(ctx: Any, ckpt: Path, name: str = "ompn_node", **params: Any) -> OMPNNode:
    overrides = [Parameter("checkpoint", value=str(ckpt))]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return OMPNNode(name, context=ctx, parameter_overrides=overrides)


def pump(ex: Any, until: Callable[[], bool], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
        if until():
            return True
    return until()


def test_a_hysteresis_above_high_is_refused_with_the_reason(ctx: Any, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, detector_high=0.3)
    result = node.set_parameters([Parameter("detector_hysteresis", value=0.5)])[0]
    assert not result.successful
    assert "detector_hysteresis" in result.reason and "detector_high" in result.reason
    assert node.values["detector_hysteresis"] == 0.0
    both = node.set_parameters_atomically(
        [Parameter("detector_high", value=0.6), Parameter("detector_hysteresis", value=0.5)]
    )
    assert both.successful  # a valid pair set together
    node.destroy_node()


@pytest.mark.parametrize("n", [2_000, pytest.param(10_000, marks=pytest.mark.slow)])
def test_a_marker_flood_is_processed_or_counted(ctx: Any, ckpt: Path, n: int) -> None:
    """Every marker is handled or counted as lost: the sum is what was sent (the node's queue held 100
    markers, so each burst of 400 lost most of them without a trace).  10 000 markers take ~20 s."""
    node = make_node(ctx, ckpt, name=f"flooded{n}")
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    peer = rclpy.create_node("flooder", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(peer)
    pub = peer.create_publisher(DiagnosticArray, layout.EPISODE,
                                QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE))  # fmt: skip
    assert pump(ex, lambda: pub.get_subscription_count() > 0)
    pump(ex, lambda: False, 0.3)

    def handled() -> int:
        c = node.counters()
        return c["markers"] + c["markers_lost"]

    start = time.monotonic()
    for i in range(n):  # bursts of 400 (the node had a queue of 100), each served before the next
        pub.publish(marker(layout.EPISODE_START if i % 2 == 0 else layout.EPISODE_END, sketch=""))
        if i % 400 == 399:
            pump(ex, lambda i=i: handled() >= i + 1, timeout=10)
    took_s = time.monotonic() - start
    pump(ex, lambda: False, 0.2)
    c = node.counters()
    assert c["markers"] + c["markers_lost"] == n, (c, took_s)
    assert c["episode_starts"] == n // 2 - c["markers_lost"] // 2 or c["markers_lost"] > 0, c
    node.destroy_node()
    peer.destroy_node()


class Peer:
    """Publishes /clock, records /diagnostics statuses of ``status`` and spins with the node(s)."""

    def __init__(self, ctx: Any, nodes: list[OMPNNode], status: str) -> None:
        from rosgraph_msgs.msg import Clock

        self.node = rclpy.create_node("clock_peer", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        for n in [*nodes, self.node]:
            self.ex.add_node(n)
        self.clock_pub = self.node.create_publisher(Clock, "/clock", 10)
        self.clock_type = Clock
        self.statuses: list[DiagnosticStatus] = []
        self.node.create_subscription(
            DiagnosticArray, "/diagnostics",
            lambda m: self.statuses.extend(s for s in m.status if s.name == status), 100,
        )  # fmt: skip

    def clock(self, ns: int) -> None:
        from builtin_interfaces.msg import Time

        msg = self.clock_type(clock=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000))
        self.clock_pub.publish(msg)
        pump(self.ex, lambda: False, 0.15)

    def counters(self) -> dict[str, str]:
        return {kv.key: kv.value for kv in self.statuses[-1].values} if self.statuses else {}


def test_negative_and_leaping_sim_clocks(ctx: Any, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, name="simclock", use_sim_time=True, diagnostics_period=0.1)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    peer = Peer(ctx, [node], "/simclock: segmenter")
    assert pump(peer.ex, lambda: peer.clock_pub.get_subscription_count() > 0)
    second = 1_000_000_000
    peer.clock(1004 * second)
    assert pump(peer.ex, lambda: node.get_clock().now().nanoseconds == 1004 * second)
    for _ in range(3):  # a simulator restarted an hour back: rclpy 7.1.6 raises ValueError in its handler
        peer.clock(-2596 * second)
    assert node.events["clock_negative"] >= 1 and node.get_clock().now().nanoseconds == 1004 * second
    starts = node.events["episode_starts"]
    peer.clock(1005 * second)
    peer.clock((1005 + 7200) * second)  # two hours ahead: a new episode, counted
    assert pump(peer.ex, lambda: node.events["clock_jumps_forward"] == 1)
    assert node.events["episode_starts"] == starts + 1
    assert pump(peer.ex, lambda: peer.counters().get("clock_jumps_forward") == "1")
    node.destroy_node()
    peer.node.destroy_node()


def test_a_stalled_sim_clock_is_reported_once_and_diagnostics_go_on(ctx: Any, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, name="stalled", use_sim_time=True, diagnostics_period=0.1, clock_stall=0.5)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    peer = Peer(ctx, [node], "/stalled: segmenter")
    assert pump(peer.ex, lambda: peer.clock_pub.get_subscription_count() > 0)
    peer.clock(50 * 1_000_000_000)
    assert pump(peer.ex, lambda: node.get_clock().now().nanoseconds > 0)
    seen = len(peer.statuses)
    pump(peer.ex, lambda: False, 1.5)  # /clock stands still for 1.5 s of wall time
    assert len(peer.statuses) - seen >= 5  # /diagnostics kept going (a steady-clock timer)
    assert node.events["clock_stalls"] == 1 and peer.counters()["clock_stalls"] == "1"
    peer.clock(51 * 1_000_000_000)  # moves again, then a second stall is a second report
    pump(peer.ex, lambda: node.events["clock_stalls"] == 2, 2.0)
    assert node.events["clock_stalls"] == 2
    node.destroy_node()
    peer.node.destroy_node()


def test_a_second_node_of_the_same_name_is_reported(ctx: Any, ckpt: Path) -> None:
    first = make_node(ctx, ckpt, name="twin", diagnostics_period=0.1)
    second = make_node(ctx, ckpt, name="twin", diagnostics_period=0.1)
    for node in (first, second):
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    peer = Peer(ctx, [first, second], "/twin: segmenter")
    assert pump(peer.ex, lambda: any("duplicate node name" in s.message for s in peer.statuses))
    status = next(s for s in peer.statuses if "duplicate node name" in s.message)
    assert status.level == b"\x01" and {kv.key: kv.value for kv in status.values}["duplicate_names"] == "1"
    for node in (first, second):
        node.destroy_node()
    peer.node.destroy_node()


def test_activate_after_a_failed_configure_is_refused(ctx: Any, ckpt: Path, tmp_path: Path) -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    node = make_node(ctx, tmp_path / "missing", name="unconfigurable")
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    serve = node._service_change_state.callback  # what the executor runs for a ~/change_state request
    request = ChangeState.Request(transition=Transition(id=Transition.TRANSITION_ACTIVATE))
    response = serve(request, ChangeState.Response())  # rclpy 7.1.6 alone raises RCLError here
    assert response.success is False
    assert node._state_machine.current_state[1] == "unconfigured"
    node.destroy_node()


FLOODER = """
import sys, time
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
n, depth, topic, name, key = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5]
rclpy.init()
node = rclpy.create_node("deep_flooder")
qos = QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(DiagnosticArray, topic, qos)
deadline = time.monotonic() + 20
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.01)
def marker(kind):
    status = DiagnosticStatus(name=name, message=kind, values=[KeyValue(key=key, value="")])
    return DiagnosticArray(status=[status])
pub.publish(marker("start"))  # the first marker; the flood waits until the node has it and acked it
if not pub.wait_for_all_acked(rclpy.duration.Duration(seconds=20)):
    sys.exit("the node never acknowledged the first marker")
sys.stdin.readline()
start = time.monotonic()
for i in range(1, n):
    pub.publish(marker("start" if i % 2 == 0 else "end"))
print(f"published {n} in {time.monotonic() - start:.2f} s", flush=True)
acked = pub.wait_for_all_acked(rclpy.duration.Duration(seconds=60))
print(f"acked {acked} after {time.monotonic() - start:.2f} s", flush=True)
node.destroy_node()
rclpy.shutdown()
"""


def flood_from_another_process(
    ctx: Any, ckpt: Path, env: dict[str, str], n: int, depth: int
) -> tuple[dict[str, int], str]:
    """A publisher with a queue of ``depth`` sends ``n`` markers as fast as it can from another process and
    waits until all are acknowledged; the node's counters once it has served its queue, and what the
    publisher printed.

    The flood starts once the node has the publisher's first marker and acknowledged it, not after a
    pause.  DDS matches a publisher and a subscription on each side on its own (under load one side can
    match seconds after the other): the publisher seeing the node's subscription does not mean that the
    subscription sees the publisher yet.  What is sent in between never reaches the node and is not
    reported lost either: for the middleware the node joined later.  The reliable first marker reaches
    the node once its side has matched; Fast DDS's reader counts losses only from the first heartbeat
    of the publisher it processed, and acknowledges only in answer to one.  From then on, every marker
    is the node's to step or count."""
    import sys

    node = make_node(ctx, ckpt, name=f"deepflood{n}_{depth}")
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    args = [str(n), str(depth), layout.EPISODE, layout.EPISODE_STATUS_NAME, layout.KEY_SKETCH]
    proc = NodeProcess(env, program=[sys.executable, "-c", FLOODER, *args], stdin=True)

    def total() -> int:
        c = node.counters()
        return c["markers"] + c["markers_lost"]

    try:
        pump(ex, lambda: total() >= 1 or not proc.running(), timeout=60)
        assert total() == 1, f"the node never had the first marker ({node.counters()}): {proc.stop()}"
        proc.send("flood")
        pump(ex, lambda: total() >= n or not proc.running(), timeout=90)
        pump(ex, lambda: total() >= n, timeout=30)  # all acknowledged: the node reads its queue
        proc.wait(timeout=30)
    finally:
        out = proc.stop()
    counters = node.counters()
    node.destroy_node()
    return counters, f"rc {proc.returncode}: {out}"


@pytest.mark.parametrize("n", [2_000, pytest.param(10_000, marks=pytest.mark.slow)])
def test_a_deep_queued_marker_flood_is_processed_or_counted(
    ctx: Any, ckpt: Path, ros_env: dict[str, str], monkeypatch: pytest.MonkeyPatch, n: int
) -> None:
    """A publisher whose queue is deeper than the node's (KEEP_LAST n, RELIABLE) sends n markers at once
    from another process: every one is handled or counted as lost, and the counters agree.  A KEEP_LAST
    marker queue (5 000, or 1 000 in the short variant) overwrote the unread ones without a count; read
    KEEP_ALL, a full queue holds the publisher back, and the short variant's depth no longer matters."""
    if n < ompn_node_inputs.MARKER_QUEUE:  # the short variant: a node queue below the flood, as the long one
        monkeypatch.setattr(ompn_node_inputs, "MARKER_QUEUE", n // 2)
    c, out = flood_from_another_process(ctx, ckpt, ros_env, n, n)
    assert out.startswith("rc 0:"), out
    assert c["markers"] + c["markers_lost"] == n, (c, out)
    if c["markers_lost"] == 0:  # every second marker is a 'start'
        assert c["episode_starts"] == n // 2, c


def test_a_shallow_queued_marker_flood_is_counted_as_lost(
    ctx: Any, ckpt: Path, ros_env: dict[str, str]
) -> None:
    """A reliable publisher with the default queue of 10 overwrites markers the node has not yet
    acknowledged: the node hears of the gap and counts it (markers_lost), so the sum is still what was
    sent."""
    n = 6_000
    c, out = flood_from_another_process(ctx, ckpt, ros_env, n, 10)
    assert out.startswith("rc 0:"), out
    assert c["markers"] + c["markers_lost"] == n, (c, out)
