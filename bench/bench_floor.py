"""What the machine costs before ``ompn_node`` does any work: the floor under its latency figures.

1. DDS floor: an echo node in its own process (raw subscription, best effort, like ``ompn_node``'s
   ``obs_qos`` default) answers each observation with a pre-encoded ``DiagnosticArray`` on a
   reliable, transient-local topic (the ``~/boundary`` QoS); this process publishes Craft-sized
   observations (1 075 floats) at 100 Hz and stamps the replies on arrival, as
   ``bench/bench_node.py`` does.  Both on the EventsExecutor, inside the loopback profile.  The
   figures: observation -> reply p10/p50/p90/p99, and the share of replies slower than 2 ms.
   Whatever ``ompn_node`` adds to its boundary latency comes on top of this p50.
2. Cold step: ``StreamingSegmenter.step`` on the shipped Craft and Dial checkpoints, once right
   after the previous step (warm caches, the figure of ``bench_node``'s in-process part) and once
   after a 10 ms sleep (the gap between observations at 100 Hz, in which other processes run).

Run: ``.venv/bin/python bench/bench_floor.py [--quick]`` from the repository root.
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from ompn_ros.ros import containment  # noqa: E402 (after the path insert)

containment.contain(os.environ)  # loopback + shared memory only, a per-run ROS_DOMAIN_ID

Result = dict[str, tuple[float, str]]
OBS_FLOATS = 1075  # Craft's observation
SLOW_MS = 2.0


def _qos() -> tuple[Any, Any]:
    """(observation QoS of the echo's subscription, reply QoS): ompn_node's defaults."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    obs = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    reply = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return obs, reply


def echo_node() -> None:
    """The echo process: every observation is answered at once, until SIGINT/SIGTERM."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float32MultiArray

    from ompn_ros.ros.run import make_executor

    rclpy.init()
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):  # after init: replaces rclpy's handlers
        signal.signal(sig, lambda *_: stop.append(True))
    node = rclpy.create_node("floor_echo")
    obs_qos, reply_qos = _qos()
    pub = node.create_publisher(DiagnosticArray, "reply", reply_qos)
    status = DiagnosticStatus(name="echo", values=[KeyValue(key="detected_at", value="0")])
    raw = serialize_message(DiagnosticArray(status=[status]))
    node.create_subscription(Float32MultiArray, "observation", lambda _: pub.publish(raw), obs_qos, raw=True)
    executor = make_executor("events")
    executor.add_node(node)
    gc.collect()
    gc.freeze()
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown()


def _pace(executor: Any, pub: Any, raw: bytes, count: int, period_ns: int) -> list[int]:
    """Publish ``raw`` ``count`` times every ``period_ns`` while serving callbacks; the send times."""
    sent = []
    due = time.monotonic_ns() + period_ns
    for _ in range(count):
        while (now := time.monotonic_ns()) < due:
            if due - now > 400_000:
                executor.spin_once(timeout_sec=(due - now - 300_000) / 1e9)
            elif due - now > 150_000:
                time.sleep((due - now - 100_000) / 1e9)
        sent.append(time.monotonic_ns())
        pub.publish(raw)
        due += period_ns
    return sent


def bench_echo(count: int) -> Result:
    """Observation -> reply latency of the echo process at 100 Hz (``count`` observations)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float32MultiArray

    from ompn_ros.data.messages import encode_float32_array
    from ompn_ros.ros.run import make_executor

    proc = subprocess.Popen([sys.executable, __file__, "--echo-node"], env=dict(os.environ), cwd=str(ROOT))
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("floor_client", context=ctx)
        arrivals: list[int] = []
        pub = node.create_publisher(Float32MultiArray, "observation",
                                    QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(DiagnosticArray, "reply", lambda _: arrivals.append(time.monotonic_ns()),
                                 _qos()[1], raw=True)
        executor = make_executor("events", context=ctx)
        executor.add_node(node)
        deadline = time.monotonic() + 30
        while (pub.get_subscription_count() == 0 or node.count_publishers("reply") == 0) and (
            time.monotonic() < deadline
        ):
            executor.spin_once(timeout_sec=0.05)
        if pub.get_subscription_count() == 0:
            raise RuntimeError("the echo node did not come up")
        raw = encode_float32_array(np.random.default_rng(0).random(OBS_FLOATS, dtype=np.float32), "obs")
        _pace(executor, pub, raw, 50, 10_000_000)  # warm-up: matching, first deliveries
        drain = time.monotonic() + 0.5
        while time.monotonic() < drain:  # every warm-up reply in before the count starts
            executor.spin_once(timeout_sec=0.05)
        gc.collect()
        gc.freeze()
        base = len(arrivals)
        sent = _pace(executor, pub, raw, count, 10_000_000)
        deadline = time.monotonic() + 3
        while len(arrivals) - base < count and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        got = arrivals[base:]
        if len(got) != count:
            raise RuntimeError(f"{count} observations sent, {len(got)} replies")
        lat = (np.array(got) - np.array(sent)) / 1e6
        out: Result = {
            f"echo_latency_100hz_p{q}": (float(np.percentile(lat, q)), "ms") for q in (10, 50, 90, 99)
        }
        out["echo_slower_than_2ms"] = (100.0 * float(np.mean(lat > SLOW_MS)), "%")
        return out
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        rclpy.shutdown(context=ctx)


def bench_cold_step(steps: int) -> Result:
    """``StreamingSegmenter.step`` p50 right after the previous step and after a 10 ms sleep."""
    import torch

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.checkpoint import load_checkpoint
    from ompn_ros.model.streaming import StreamingPolicy
    from ompn_ros.segmenter import StreamingSegmenter

    sys.path.insert(0, str(ROOT / "bench"))
    from bench_node import _observations

    torch.set_num_threads(1)
    out: Result = {}
    for name in ("craft", "dial"):
        model, _ = load_checkpoint(shipped_checkpoint(name))
        seg = StreamingSegmenter(StreamingPolicy(model, backend="jit"), DetectorConfig(high=0.5))
        obs, starts = _observations(name, steps)
        begin = set(starts)
        for label, gap in (("warm", 0.0), ("after_10ms", 0.01)):
            times = []
            for i, x in enumerate(obs):
                if i in begin:
                    seg.reset()
                if gap:
                    time.sleep(gap)
                t0 = time.perf_counter_ns()
                seg.step(x)
                times.append((time.perf_counter_ns() - t0) / 1e3)
            out[f"{name}_step_{label}_p50"] = (float(np.percentile(times[50:], 50)), "us")
    return out


def run(quick: bool = False) -> Result:
    """Every figure (name -> (value, unit)); ``quick`` = fewer samples."""
    results = bench_cold_step(500 if quick else 2000)
    results.update(bench_echo(300 if quick else 3000))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples (less precise figures)")
    parser.add_argument("--echo-node", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo_node:
        echo_node()
        return
    results = run(quick=args.quick)
    width = max(len(k) for k in results)
    for name, (value, unit) in results.items():
        print(f"{name:<{width}}  {value:12.3f}  {unit}")


if __name__ == "__main__":
    main()
