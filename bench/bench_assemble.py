"""Benchmark of the observation assembly from several topics over DDS (``ompn_ros.data.obs``).

A publisher process plays an arm at 1 kHz: per tick a ``WrenchStamped`` and a gripper
``Float32MultiArray`` (the two extra topics), then the step topic ``JointState`` (7 joints, position
and velocity), all RELIABLE with depth 1000.  This process subscribes (raw CDR, EventsExecutor driven
by ``spin_once``) and feeds two :class:`ObservationAssembler` (``hold`` / ``release``, as
``ompn_node``): the measured one with ``stamp: receive`` (every stamp on this process's clock; it
never waits) and one with ``stamp: header`` (the publisher's header stamps for JointState and
WrenchStamped, the gripper at reception; a step waits for the wrench stamped at or after it,
``wait_s`` 0.1 s).  Figures, over ``duration`` s (60 s; 10 s with ``quick``):

* ``steps_sent``, ``steps_received``, ``steps_assembled``, ``step_loss`` = 1 − assembled / sent
  (target 0), ``steps_per_s`` (assembled per second of publishing);
* ``assemble_p50_us`` / ``assemble_p99_us``: ``ObservationAssembler.step`` wall time per step;
* ``offer_p50_us``: ``offer`` wall time per partner message;
* ``receive_rule_dropped``, ``header_rule_dropped``: steps dropped by each rule (target 0);
* ``header_rule_kept_ratio``: kept / received of the ``stamp: header`` assembler, ``header_rule_late``
  its steps decided at the end of their wait, ``header_rule_wait_p50_ms`` / ``_p99_ms`` how long it
  held its kept steps (from the step's reception to its release);
* ``max_gap_<topic>_ms``: the longest time this process received nothing on a topic.  A partner
  topic whose delivery stalls longer than the tolerance (50 ms; e.g. a reliable-repair pause of DDS on
  a loaded machine) makes the steps of that stall ``stale``: counted drops, by the rule;
* ``offline_msgs_per_s``: ``assemble_stream`` over the same messages replayed from memory.

Run: ``.venv/bin/python bench/bench_assemble.py [--quick]`` from the repository root.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from ompn_ros.ros import containment  # noqa: E402 (after the path insert)

containment.contain(os.environ)  # loopback + shared memory only, a per-run ROS_DOMAIN_ID

from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec  # noqa: E402

Result = dict[str, tuple[float, str]]
RATE_HZ = 1000
JOINTS = [f"joint_{i}" for i in range(1, 8)]
SPEC = {
    "step_topic": "/arm/joint_states",
    "tolerance_s": 0.05,
    "fields": [
        {"topic": "/arm/joint_states", "type": "JointState", "field": "position", "names": JOINTS},
        {"topic": "/arm/joint_states", "type": "JointState", "field": "velocity", "names": JOINTS},
        {"topic": "/arm/gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 2},
        {"topic": "/arm/wrench", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"},
    ],
}

PUBLISHER = textwrap.dedent("""
    import sys, time
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float32MultiArray

    duration, rate, joints = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3].split(",")
    rclpy.init()
    node = rclpy.create_node("bench_arm")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    js = node.create_publisher(JointState, "/arm/joint_states", qos)
    grip = node.create_publisher(Float32MultiArray, "/arm/gripper", qos)
    ft = node.create_publisher(WrenchStamped, "/arm/wrench", qos)
    deadline = time.monotonic() + 30
    while min(p.get_subscription_count() for p in (js, grip, ft)) == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    clock = node.get_clock()
    msg, w, g = JointState(), WrenchStamped(), Float32MultiArray()
    msg.name = joints
    period, start = 1.0 / rate, time.monotonic()
    n = int(duration * rate)
    for k in range(n):
        delay = start + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        w.header.stamp = clock.now().to_msg()
        w.wrench.force.x = float(k)
        ft.publish(w)
        g.data = [0.001 * (k % 1000), 1.0]
        grip.publish(g)
        msg.header.stamp = clock.now().to_msg()
        msg.position = [float(k)] * len(joints)
        msg.velocity = [0.5] * len(joints)
        js.publish(msg)
    elapsed = time.monotonic() - start
    time.sleep(2.0)
    print(f"SENT {n} {elapsed:.6f}", flush=True)
    node.destroy_node()
    rclpy.shutdown()
""")


def _pct(values: list[int], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) / 1e3 if values else float("nan")


class _Subscriber:
    """Raw subscriptions feeding the measured (receive) and the header-rule assembler."""

    def __init__(self, ctx: Any) -> None:
        import rclpy
        from geometry_msgs.msg import WrenchStamped
        from rclpy.experimental import EventsExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float32MultiArray


        self.step_topic = SPEC["step_topic"]
        self.header_asm = ObservationAssembler(ObservationSpec.from_dict({**SPEC, "stamp": "header"}))
        self.asm = ObservationAssembler(ObservationSpec.from_dict({**SPEC, "stamp": "receive"}))
        self.step_ns: list[int] = []
        self.header_wait_ns: list[int] = []  # how long the header rule held each kept step
        self.offer_ns: list[int] = []
        self.recorded: list[tuple[str, int, bytes]] = []
        self.last = 0
        self.last_seen: dict[str, int] = {}
        self.max_gap_ns: dict[str, int] = {}  # longest time without a message, per topic
        self.node = rclpy.create_node("bench_assembler", context=ctx)
        self.ex = EventsExecutor(context=ctx)
        self.ex.add_node(self.node)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        for topic, cls in (("/arm/joint_states", JointState), ("/arm/gripper", Float32MultiArray),
                           ("/arm/wrench", WrenchStamped)):
            self.node.create_subscription(cls, topic, self._callback(topic), qos, raw=True)

    def _callback(self, topic: str) -> Any:
        step = topic == self.step_topic

        def on_message(raw: bytes) -> None:
            now = self.last = max(time.time_ns(), self.last + 1)
            previous = self.last_seen.get(topic)
            if previous is not None:
                self.max_gap_ns[topic] = max(self.max_gap_ns.get(topic, 0), now - previous)
            self.last_seen[topic] = now
            self.recorded.append((topic, now, raw))
            t0 = time.perf_counter_ns()
            if step:
                self.asm.hold(now, raw)
                self.asm.release(now)
                self.step_ns.append(time.perf_counter_ns() - t0)
                self.header_asm.hold(now, raw)
            else:
                self.asm.offer(topic, now, raw)
                self.asm.release(now)
                self.offer_ns.append(time.perf_counter_ns() - t0)
                self.header_asm.offer(topic, now, raw)
            for d in self.header_asm.release(now):
                if not isinstance(d.result, Drop):
                    self.header_wait_ns.append(now - d.receive_ns)

        return on_message


def bench_dds(duration: float) -> Result:
    """Publisher process at 1 kHz (+ two extra topics), assembler in this process."""
    import rclpy

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(duration), str(RATE_HZ), ",".join(JOINTS)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        sub = _Subscriber(ctx)
        deadline = time.monotonic() + duration + 60
        while proc.poll() is None and time.monotonic() < deadline:
            sub.ex.spin_once(timeout_sec=0.05)
        for _ in range(20):  # drain what is still queued
            sub.ex.spin_once(timeout_sec=0.05)
        sub.asm.release(flush=True)  # the end of the stream
        sub.header_asm.release(flush=True)
    finally:
        rclpy.try_shutdown(context=ctx)
        if proc.poll() is None:
            proc.kill()
        out = proc.communicate()[0]
    sent_line = [line for line in out.splitlines() if line.startswith("SENT ")]
    if not sent_line:
        raise RuntimeError(f"publisher failed: {out[-2000:]}")
    sent, elapsed = int(sent_line[0].split()[1]), float(sent_line[0].split()[2])
    stats, hstats = sub.asm.stats, sub.header_asm.stats
    print(f"   receive rule: {stats.as_dict()}\n   header rule: {hstats.as_dict()}", flush=True)
    result: Result = {
        "steps_sent": (float(sent), "steps"),
        "steps_received": (float(stats.steps), "steps"),
        "steps_assembled": (float(stats.kept), "steps"),
        "step_loss": (1.0 - stats.kept / sent, "fraction (target 0)"),
        "steps_per_s": (stats.kept / elapsed, "steps/s"),
        "publish_rate": (sent / elapsed, "steps/s"),
        "assemble_p50_us": (_pct(sub.step_ns, 50), "us"),
        "assemble_p99_us": (_pct(sub.step_ns, 99), "us"),
        "offer_p50_us": (_pct(sub.offer_ns, 50), "us"),
        "receive_rule_dropped": (float(sum(stats.dropped.values())), "steps"),
        "header_rule_kept_ratio": (hstats.kept / max(hstats.steps, 1), "fraction"),
        "header_rule_dropped": (float(sum(hstats.dropped.values())), "steps"),
        "header_rule_late": (float(hstats.late), "steps"),
        "header_rule_wait_p50_ms": (_pct(sub.header_wait_ns, 50) / 1e3, "ms"),
        "header_rule_wait_p99_ms": (_pct(sub.header_wait_ns, 99) / 1e3, "ms"),
    }
    for topic, gap in sorted(sub.max_gap_ns.items()):  # delivery stalls explain 'stale' drops
        result[f"max_gap_{topic.rsplit('/', 1)[-1]}_ms"] = (gap / 1e6, "ms")
    result.update(bench_offline(sub.recorded))
    return result


def bench_offline(recorded: list[tuple[str, int, bytes]]) -> Result:
    """``assemble_stream`` over the recorded messages (no DDS, no storage)."""
    from ompn_ros.data.obs import ObservationSpec, assemble_stream

    spec = ObservationSpec.from_dict({**SPEC, "stamp": "receive"})
    t0 = time.perf_counter()
    res = assemble_stream(recorded, spec)
    seconds = time.perf_counter() - t0
    return {"offline_msgs_per_s": (len(recorded) / seconds, "messages/s"),
            "offline_kept": (float(res.stats.kept), "steps")}


def run(quick: bool = False) -> Result:
    """All figures (see the module docstring)."""
    return bench_dds(10.0 if quick else 60.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s instead of 60 s")
    args = parser.parse_args()
    for name, (value, unit) in run(args.quick).items():
        print(f"{name:<24} {value:>14.4g}  {unit}")


if __name__ == "__main__":
    main()
