"""Sim time: the sims publish their clock (<ns>/clock under a namespace, so that namespaced sims never
interleave on /clock), run under use_sim_time:=true, and stamp everything in one time base."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from sim_listener import RELIABLE, Listener, finish, launch, stamp_ns  # noqa: E402

from ompn_ros import layout  # noqa: E402

BEST_EFFORT = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
STEP_NS = layout.STEP_NS


def _run_dial(ros_env: dict[str, str], ns: str, clock_qos: QoSProfile, *params: str,
              publish_clock: Callable[[Listener], None] | None = None) -> tuple[Listener, int | None, str]:
    lis = Listener()
    lis.listen("/clock", Clock, clock_qos)
    lis.listen(f"/{ns}/clock", Clock, clock_qos)
    lis.listen(f"/{ns}/{layout.JOINT_STATES}", JointState, qos_profile_sensor_data)
    lis.listen(f"/{ns}/{layout.EPISODE}", DiagnosticArray, RELIABLE)
    proc = launch(ros_env, ns, "use_sim_time:=true", "rate:=200.0", "episodes:=2", "sketch:=[1,2,3,4]",
                  "wait_for_subscribers:=1", "wait_topics:=[episode, joint_states]", *params)
    try:
        tick = publish_clock or (lambda _lis: None)
        end = time.monotonic() + 90
        while time.monotonic() < end and len(lis.of(f"/{ns}/{layout.EPISODE}")) < 4:
            tick(lis)
            lis.spin_until(lambda: False, timeout=0.05)
        lis.spin_until(lambda: False, timeout=0.3)
        code, err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return lis, code, err


def test_sim_publishes_clock_and_stamps_in_its_time(ros_env: dict[str, str]) -> None:
    ns = f"simtime_{uuid.uuid4().hex[:6]}"
    lis, code, err = _run_dial(ros_env, ns, BEST_EFFORT)  # the QoS rclpy's own time source subscribes with
    lis.close()
    assert code == 0, err
    markers = lis.of(f"/{ns}/{layout.EPISODE}")
    joints = lis.of(f"/{ns}/{layout.JOINT_STATES}")
    clock = [stamp_ns(m.clock) for m in lis.of(f"/{ns}/clock")]
    assert len(markers) == 4 and len(joints) > 40, err
    assert len(clock) > 40 and clock == sorted(clock)  # it advances, never back
    assert lis.of("/clock") == []  # a namespaced sim keeps its clock in its namespace
    js = [stamp_ns(m.header.stamp) for m in joints]
    ticks = set(clock)
    # One time base: every stamp IS a /clock value (best effort may drop some /clock samples, so
    # compare with the nearest one: within one step period, not decades apart).
    for stamp in js + [stamp_ns(m.header.stamp) for m in markers]:
        assert min(abs(stamp - c) for c in ticks) < STEP_NS, (stamp, clock[:3])
    start0, end0, start1, _ = (stamp_ns(m.header.stamp) for m in markers)
    steps0 = int({kv.key: kv.value for kv in markers[1].status[0].values}[layout.KEY_STEPS])
    assert end0 - start0 == steps0 * STEP_NS  # 40 ms of simulated time per step, markers included
    assert start1 - end0 >= layout.EPISODE_GAP_NS  # the gap between episodes in simulated time
    # Best effort may drop a JointState under load, so check each stamp's place instead of counting:
    # every JointState lies on its episode's 40 ms grid that starts at the start marker's stamp.
    for stamp in js:
        first = start0 if stamp <= end0 else start1
        assert stamp >= first and (stamp - first) % STEP_NS == 0, (stamp, start0, end0, start1)
    assert js[0] < end0 < start1 <= js[-1]  # both episodes were seen


def test_without_publish_clock_stamps_follow_the_node_clock(ros_env: dict[str, str]) -> None:
    """publish_clock:=false under use_sim_time: every stamp is the /clock another node publishes."""
    ns = f"extclock_{uuid.uuid4().hex[:6]}"
    base = 1_000_000 * 1_000_000_000  # 1e6 s: far from both wall time and the sim's own time
    pub: list = []

    def tick(lis: Listener) -> None:
        if not pub:
            pub.append(lis.node.create_publisher(Clock, "/clock", RELIABLE))
            pub.append(0)
        pub[1] += 1
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(base + pub[1] * 10_000_000, 1_000_000_000)
        pub[0].publish(msg)

    lis, code, err = _run_dial(ros_env, ns, RELIABLE, "publish_clock:=false", publish_clock=tick)
    lis.close()
    assert code == 0, err
    ours = {stamp_ns(m.clock) for m in lis.of("/clock")}
    assert ours and max(ours) <= base + pub[1] * 10_000_000  # only the test published /clock
    stamps = [stamp_ns(m.header.stamp) for m in lis.of(f"/{ns}/{layout.JOINT_STATES}")]
    stamps += [stamp_ns(m.header.stamp) for m in lis.of(f"/{ns}/{layout.EPISODE}")]
    assert len(stamps) > 40, err
    assert all(base <= s <= base + pub[1] * 10_000_000 for s in stamps), stamps[:5]


def test_craft_sim_runs_on_its_own_clock(ros_env: dict[str, str]) -> None:
    ns = f"crafttime_{uuid.uuid4().hex[:6]}"
    lis = Listener()
    lis.listen(f"/{ns}/clock", Clock, RELIABLE)
    lis.listen(f"/{ns}/{layout.EPISODE}", DiagnosticArray, RELIABLE)
    proc = launch(ros_env, ns, "use_sim_time:=true", "rate:=0.0", "episodes:=2", "wait_for_subscribers:=1",
                  "wait_topics:=[episode]", sim="craft")  # fmt: skip
    try:
        lis.spin_until(lambda: proc.poll() is not None, timeout=60)
        lis.spin_until(lambda: False, timeout=0.3)
        code, err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        lis.close()
    assert code == 0, err
    markers = lis.of(f"/{ns}/{layout.EPISODE}")
    assert len(markers) == 4, err
    start0, end0, start1, end1 = (stamp_ns(m.header.stamp) for m in markers)
    steps = [int({kv.key: kv.value for kv in m.status[0].values}[layout.KEY_STEPS]) for m in markers[1::2]]
    assert start0 == layout.EPISODE_GAP_NS  # the sim's time, not the wall clock
    assert (end0 - start0, end1 - start1) == (steps[0] * STEP_NS, steps[1] * STEP_NS)
    assert start1 - end0 == layout.EPISODE_GAP_NS
    clock = [stamp_ns(m.clock) for m in lis.of(f"/{ns}/clock")]
    assert clock == sorted(clock) and clock[-1] == end1  # the last /clock is the final observation's time
