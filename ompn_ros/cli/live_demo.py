"""The main job: a sim and ``ompn_node`` as separate processes, segmenting live over ROS 2.

The sim (expert mode) publishes observations and the ground-truth subtask index; ``ompn_node``
steps the ordered memory on every observation and publishes boundary events.  This monitor
subscribes to both, prints every detected boundary next to the true one, and ends with the online
F1, alignment accuracy and latency summary plus a saved plot of π over time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ompn_ros import layout
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.paths import config_file
from ompn_ros.ros_env import child_env


@dataclass
class LiveEpisode:
    """What the monitor saw of one episode."""

    index: int
    obs_times: list[int] = field(default_factory=list)  # receive time (ns) of each observation
    subtask: list[int] = field(default_factory=list)
    pi_rows: list[list[float]] = field(default_factory=list)
    boundaries: list[int] = field(default_factory=list)
    detected_at: list[int] = field(default_factory=list)
    latencies_ms: list[float] = field(default_factory=list)
    steps: int = 0


def _kv(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _monitor(args: argparse.Namespace, node_name: str) -> list[LiveEpisode]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float32MultiArray, Int32

    rclpy.init()
    node = rclpy.create_node("ompn_demo_monitor")
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    events_qos = QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    episodes: list[LiveEpisode] = []
    finished: list[LiveEpisode] = []
    current: dict[str, LiveEpisode] = {}  # 'ep': the running episode; 'last': the latest one (late events)

    def on_episode(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != layout.EPISODE_STATUS_NAME:
                continue
            keys = _kv(status)
            if status.message == layout.EPISODE_START:
                ep = LiveEpisode(index=int(keys.get(layout.KEY_EPISODE, len(episodes))))
                episodes.append(ep)
                current["ep"] = current["last"] = ep
                print(f"episode {ep.index} started", flush=True)
            elif status.message == layout.EPISODE_END and "ep" in current:
                ep = current.pop("ep")
                ep.steps = int(keys.get(layout.KEY_STEPS, len(ep.subtask)))
                finished.append(ep)

    def on_obs(_msg: Float32MultiArray) -> None:
        if "ep" in current:
            current["ep"].obs_times.append(time.monotonic_ns())

    def on_subtask(msg: Int32) -> None:
        if "ep" in current:
            current["ep"].subtask.append(int(msg.data))

    def on_pi(msg: Float32MultiArray) -> None:
        if "ep" in current:
            current["ep"].pi_rows.append(list(msg.data))

    def on_boundary(msg: DiagnosticArray) -> None:
        now = time.monotonic_ns()
        ep = current.get("ep") or current.get("last")  # the final boundary can follow the end marker
        for status in msg.status:
            keys = _kv(status)
            if ep is None or "step" not in keys:
                continue
            step, seen_at = int(keys["step"]), int(keys.get("detected_at", keys["step"]))
            ep.boundaries.append(step)
            ep.detected_at.append(seen_at)
            latency = ""
            if 0 <= seen_at < len(ep.obs_times) and keys.get("final") != "true":
                ep.latencies_ms.append((now - ep.obs_times[seen_at]) / 1e6)
                latency = f", {ep.latencies_ms[-1]:.2f} ms after observation {seen_at}"
            print(f"   detected boundary: step {step:4d} (subtask {keys.get('subtask', '?')}){latency}",
                  flush=True)

    node.create_subscription(DiagnosticArray, layout.EPISODE, on_episode, reliable)
    node.create_subscription(Float32MultiArray, layout.OBSERVATION, on_obs, reliable)
    node.create_subscription(Int32, layout.SUBTASK, on_subtask, reliable)
    node.create_subscription(Float32MultiArray, f"/{node_name}/pi", on_pi, reliable)
    node.create_subscription(DiagnosticArray, f"/{node_name}/boundary", on_boundary, events_qos)
    deadline = time.monotonic() + args.timeout
    try:
        while len(finished) < args.episodes and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        # The last boundary of an episode can arrive just after its end marker.
        settle = time.monotonic() + 1.0
        while time.monotonic() < settle:
            rclpy.spin_once(node, timeout_sec=0.05)
        for ep in finished:
            _print_episode(ep)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return finished


def _true_boundaries(subtask: list[int]) -> list[int]:
    from ompn_ros.data.episode import boundaries_from_labels

    return boundaries_from_labels(np.asarray(subtask)).tolist()


def _print_episode(ep: LiveEpisode) -> None:
    """Each true boundary next to the nearest detection, then any detection that matched none."""
    truth = _true_boundaries(ep.subtask)
    detected = sorted(set(ep.boundaries))
    print(f"episode {ep.index}: {len(ep.subtask)} steps")
    for i, t in enumerate(truth):
        near = min(detected, key=lambda d: abs(d - t)) if detected else None
        shown = "none" if near is None else f"{near:4d} (Δ{near - t:+d})"
        print(f"   subtask {i}: true boundary {t:4d}   detected {shown}")
    extra = [d for d in detected if min(abs(d - t) for t in truth) > 1] if truth else detected
    if extra:
        print(f"   detections more than 1 step from any true boundary: {extra}")


def _summarise(episodes: list[LiveEpisode], out_dir: Path) -> dict[str, float]:
    from ompn_ros.metrics import alignment_accuracy, f1_with_tolerance

    f1_0, f1_1, aligned, total, lat = [], [], 0.0, 0, []
    for ep in episodes:
        truth = np.asarray(_true_boundaries(ep.subtask))
        pred = np.asarray(sorted(set(ep.boundaries)), dtype=np.int64)
        f1_0.append(f1_with_tolerance(pred, truth, tol=0).f1)
        f1_1.append(f1_with_tolerance(pred, truth, tol=1).f1)
        acc = alignment_accuracy([pred], [np.asarray(ep.subtask)], variant="strict")
        aligned += acc * len(ep.subtask)
        total += len(ep.subtask)
        lat.extend(ep.latencies_ms)
    summary = {
        "episodes": len(episodes),
        "f1_tol0": float(np.mean(f1_0)) if f1_0 else float("nan"),
        "f1_tol1": float(np.mean(f1_1)) if f1_1 else float("nan"),
        "align_acc": aligned / total if total else float("nan"),
        "latency_ms_p50": float(np.percentile(lat, 50)) if lat else float("nan"),
        "latency_ms_p99": float(np.percentile(lat, 99)) if lat else float("nan"),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    if episodes and episodes[0].pi_rows:
        from ompn_ros.detect.online import expansion_scores
        from ompn_ros.plotting import plot_episode

        ep = episodes[0]
        rows = np.asarray(ep.pi_rows[: len(ep.subtask)], dtype=np.float64)
        pi, pi_end = rows[:, :-2], rows[:, -1]
        # ~/pi carries the normalised slots (lowest first); p_hat is [π_end, top … bottom] unnormalised.
        p_hat = np.concatenate([pi_end[:, None], pi[:, ::-1] * (1.0 - pi_end[:, None])], axis=1)
        plot_episode(out_dir / "live_episode0.png", pi, pi_end, expansion_scores(p_hat),
                     true_boundaries=_true_boundaries(ep.subtask), detected_boundaries=ep.boundaries,
                     title=f"live episode {ep.index} (received over ROS 2)")
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", choices=sorted(layout.DOMAINS), default="dial")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--rate", type=float, default=100.0, help="sim rate in Hz (Dial real time is 25)")
    parser.add_argument("--seed", type=int, default=1000, help="first episode seed (held out from training)")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped one")
    parser.add_argument("--out", type=Path, default=Path("out/demo"))
    parser.add_argument("--timeout", type=float, default=300.0)
    args = parser.parse_args(argv)

    checkpoint = args.checkpoint or shipped_checkpoint(args.domain)
    env = child_env()
    sim = f"{args.domain}_sim"
    node_name = "ompn_node"
    start = time.perf_counter()
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "ompn_ros.nodes.ompn_node", "--ros-args",
             "--params-file", str(config_file(f"ompn_node_{args.domain}.yaml")),
             "-p", f"checkpoint:={checkpoint}", "-r", f"__node:={node_name}"],
            env=env,
        ))
        # The sim holds its first episode until ompn_node and this monitor subscribe to observation.
        procs.append(subprocess.Popen(
            [sys.executable, "-m", f"sim_nodes.{args.domain}.node", "--ros-args",
             "-p", "mode:=expert", "-p", f"rate:={args.rate}", "-p", f"seed:={args.seed}",
             "-p", f"episodes:={args.episodes}", "-p", "wait_for_subscribers:=2",
             "-p", "wait_topics:=[observation]"],
            env=env,
        ))
        print(f"{sim} and ompn_node running (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}); "
              f"segmenting {args.episodes} episodes live with {checkpoint}")
        episodes = _monitor(args, node_name)
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
    if not episodes:
        print("no complete episode was observed", file=sys.stderr)
        return 1
    summary = _summarise(episodes, args.out)
    print(f"\nonline segmentation over ROS 2: {summary['episodes']} episodes, "
          f"F1(tol=0) {summary['f1_tol0']:.3f}, F1(tol=1) {summary['f1_tol1']:.3f}, "
          f"alignment {summary['align_acc']:.3f}, "
          f"observation→boundary latency p50 {summary['latency_ms_p50']:.2f} ms, "
          f"p99 {summary['latency_ms_p99']:.2f} ms")
    print(f"plot and summary in {args.out}/  ({time.perf_counter() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
