"""Live segmentation over ROS 2, monitored: what ``ompn_demo`` runs (the sim and ``ompn_node`` as
separate processes, this monitor subscribing to both).

The monitor cuts its streams into episodes, prints every detected boundary next to the true one and
summarises the online F1 (tolerance 0 and 1), the strict alignment accuracy and the
observation-to-boundary latency (Lu et al., ICLR 2021, §4 metrics, measured causally).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros import layout
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import boundaries_from_labels
from ompn_ros.data.messages import EPISODE_END, SubtaskBoundary, decode_subtask_boundary
from ompn_ros.detect.online import expansion_scores
from ompn_ros.metrics import alignment_accuracy, f1_with_tolerance
from ompn_ros.paths import config_file
from ompn_ros.plotting import plot_episode
from ompn_ros.ros.env import child_env

DOMAINS = layout.DOMAINS
"""The simulators the demo runs (the choices of its ``--domain``)."""


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


def _kv(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@dataclass
class Streams:
    """Everything the monitor received, per topic, in arrival order.

    DDS keeps the order within a topic but not across topics, so episodes are cut from each stream
    by counts (an episode of T steps has T subtask labels and T + 1 observations and π rows), and
    the boundary stream by the events' episode number.
    """

    ends: list[dict[str, str]] = field(default_factory=list)
    obs_times: list[int] = field(default_factory=list)
    subtask: list[int] = field(default_factory=list)
    pi_rows: list[list[float]] = field(default_factory=list)
    boundaries: list[tuple[SubtaskBoundary, int]] = field(default_factory=list)  # (event, receive ns)

    def on_episode(self, msg: Any) -> None:
        """A ``diagnostic_msgs/DiagnosticArray`` on the episode topic: starts printed, ends kept."""
        for status in msg.status:
            if status.name != layout.EPISODE_STATUS_NAME:
                continue
            keys = _kv(status)
            if status.message == layout.EPISODE_START:
                print(f"episode {keys.get(layout.KEY_EPISODE, '?')} started", flush=True)
            elif status.message == layout.EPISODE_END:
                self.ends.append(keys)

    def on_boundary(self, raw: bytes) -> None:
        """A boundary event of the node (``SubtaskBoundary`` CDR): kept with its receive time, printed."""
        received = time.monotonic_ns()
        event = decode_subtask_boundary(raw)
        self.boundaries.append((event, received))
        if event.kind == EPISODE_END:  # no subtask ended with the episode: its count
            print(f"   episode end:        step {event.step:4d} ({event.subtask} subtasks)", flush=True)
            return
        final = " (episode end)" if event.final else ""
        print(f"   detected boundary: step {event.step:4d} (subtask {event.subtask}){final}", flush=True)

    def episodes(self) -> list[LiveEpisode]:
        out: list[LiveEpisode] = []
        obs0, sub0 = 0, 0
        groups: list[list[tuple[SubtaskBoundary, int]]] = []
        for event, received in self.boundaries:
            if not groups or event.episode != groups[-1][-1][0].episode:
                groups.append([])
            groups[-1].append((event, received))
        for i, end in enumerate(self.ends):
            steps = int(end.get(layout.KEY_STEPS, 0))
            ep = LiveEpisode(index=int(end.get(layout.KEY_EPISODE, len(out))), steps=steps)
            ep.obs_times = self.obs_times[obs0 : obs0 + steps + 1]
            ep.pi_rows = self.pi_rows[obs0 : obs0 + steps + 1]
            ep.subtask = self.subtask[sub0 : sub0 + steps]
            obs0, sub0 = obs0 + steps + 1, sub0 + steps
            for event, received in groups[i] if i < len(groups) else []:
                step, seen_at = event.step, event.decided_step
                # A boundary on the final (done) observation closes the last subtask, whose last real
                # step is T - 1: the same rule as the offline replay (ompn_ros.stream.replay.replay_episode);
                # the episode end (at T - 1) counts as the metrics' last boundary (Algorithm 1).
                step = min(step, max(steps - 1, 0))
                if step in ep.boundaries:
                    continue
                ep.boundaries.append(step)
                ep.detected_at.append(seen_at)
                if not event.final and 0 <= seen_at < len(ep.obs_times):
                    ep.latencies_ms.append((received - ep.obs_times[seen_at]) / 1e6)
            out.append(ep)
        return out


def monitor(episodes: int, timeout: float, node_name: str) -> list[LiveEpisode]:
    """Subscribe to the sim's and the node's topics until ``episodes`` episodes ended or ``timeout``
    seconds passed; print every detection as it arrives and each episode against its ground truth."""
    import rclpy  # ROS only when monitoring: the rest of the package is ROS-free
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float32MultiArray, Int32

    from ompn_interfaces.msg import SubtaskBoundary as SubtaskBoundaryMsg

    rclpy.init()
    node = rclpy.create_node("ompn_demo_monitor")
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    events_qos = QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    streams = Streams()

    node.create_subscription(DiagnosticArray, layout.EPISODE, streams.on_episode, reliable)

    def on_subtask(msg: Int32) -> None:
        streams.subtask.append(int(msg.data))

    def on_pi(msg: Float32MultiArray) -> None:
        streams.pi_rows.append(list(msg.data))

    node.create_subscription(Int32, layout.SUBTASK, on_subtask, reliable)
    node.create_subscription(Float32MultiArray, f"/{node_name}/pi", on_pi, reliable)
    node.create_subscription(SubtaskBoundaryMsg, f"/{node_name}/boundary", streams.on_boundary, events_qos,
                             raw=True)
    deadline = time.monotonic() + timeout
    try:
        # The sim starts once ompn_node and this monitor subscribe to observation: subscribe last,
        # when the node's outputs are matched, so that no event of the first episode is missed.
        if not wait_for_publishers(node, [f"/{node_name}/pi", f"/{node_name}/boundary"], deadline):
            print(f"{node_name}'s ~/pi and ~/boundary did not appear within {timeout:g} s", file=sys.stderr)
        node.create_subscription(
            Float32MultiArray,
            layout.OBSERVATION,
            lambda _m: streams.obs_times.append(time.monotonic_ns()),
            reliable,
        )
        while time.monotonic() < deadline and len(streams.ends) < episodes:
            rclpy.spin_once(node, timeout_sec=0.05)
        settle = time.monotonic() + 1.0  # the last messages of other topics may still be in flight
        while time.monotonic() < settle:
            rclpy.spin_once(node, timeout_sec=0.05)
    except ExternalShutdownException:
        pass  # Ctrl-C: report what arrived so far
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    found = streams.episodes()
    for ep in found:
        print_episode(ep)
    return found


def wait_for_publishers(node: Any, topics: Sequence[str], deadline: float, settle_s: float = 0.2) -> bool:
    """Spin ``node`` until every topic has a publisher (then ``settle_s`` more, for the endpoints to
    match) or ``deadline`` (``time.monotonic()``) passes; True when all were found."""
    import rclpy

    while time.monotonic() < deadline:
        if all(node.count_publishers(topic) > 0 for topic in topics):
            settle = min(deadline, time.monotonic() + settle_s)
            while time.monotonic() < settle:
                rclpy.spin_once(node, timeout_sec=0.05)
            return True
        rclpy.spin_once(node, timeout_sec=0.05)
    return False


def true_boundaries(subtask: list[int]) -> list[int]:
    return boundaries_from_labels(np.asarray(subtask)).tolist()


def print_episode(ep: LiveEpisode) -> None:
    """Each true boundary next to the nearest detection, then any detection that matched none."""
    truth = true_boundaries(ep.subtask)
    detected = sorted(set(ep.boundaries))
    print(f"episode {ep.index}: {len(ep.subtask)} steps")
    for i, t in enumerate(truth):
        near = min(detected, key=lambda d: abs(d - t)) if detected else None
        shown = "none" if near is None else f"{near:4d} (Δ{near - t:+d})"
        print(f"   subtask {i}: true boundary {t:4d}   detected {shown}")
    extra = [d for d in detected if min(abs(d - t) for t in truth) > 1] if truth else detected
    if extra:
        print(f"   detections more than 1 step from any true boundary: {extra}")


def summarise(episodes: list[LiveEpisode], out_dir: Path) -> dict[str, float]:
    f1_0, f1_1, aligned, total, lat = [], [], 0.0, 0, []
    for ep in episodes:
        truth = np.asarray(true_boundaries(ep.subtask))
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
        ep = episodes[0]
        rows = np.asarray(ep.pi_rows[: len(ep.subtask)], dtype=np.float64)
        pi, pi_end = rows[:, :-2], rows[:, -1]
        # ~/pi carries the normalised slots (lowest first); p_hat is [π_end, top … bottom] unnormalised.
        p_hat = np.concatenate([pi_end[:, None], pi[:, ::-1] * (1.0 - pi_end[:, None])], axis=1)
        plot_episode(
            out_dir / "live_episode0.png",
            pi,
            pi_end,
            expansion_scores(p_hat),
            true_boundaries=true_boundaries(ep.subtask),
            detected_boundaries=ep.boundaries,
            title=f"live episode {ep.index} (received over ROS 2)",
        )
    return summary


def launch(
    domain: str, checkpoint: Path, rate: float, seed: int, episodes: int, node_name: str,
    params_file: Path | None = None, sim_params: Sequence[str] = (),
) -> tuple[list[subprocess.Popen[bytes]], dict[str, str]]:
    """Start ``ompn_node`` (``params_file``, default ``config/ompn_node_<domain>.yaml``) and the domain's
    sim (expert mode, plus ``sim_params``, each ``NAME:=VALUE``) as processes; returns them and their env."""
    env = child_env()
    node = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ompn_ros.nodes.ompn_node",
            "--ros-args",
            "--params-file",
            str(params_file or config_file(f"ompn_node_{domain}.yaml")),
            "-p",
            f"checkpoint:={checkpoint}",
            "-r",
            f"__node:={node_name}",
        ],
        env=env,
    )
    try:
        # The sim holds its first episode until ompn_node and this monitor subscribe to observation.
        sim = subprocess.Popen(
            [
                sys.executable,
                "-m",
                f"sim_nodes.{domain}.node",
                "--ros-args",
                "-p",
                "mode:=expert",
                "-p",
                f"rate:={rate}",
                "-p",
                f"seed:={seed}",
                "-p",
                f"episodes:={episodes}",
                "-p",
                "wait_for_subscribers:=2",
                "-p",
                "wait_topics:=[observation]",
                *(arg for param in sim_params for arg in ("-p", param)),
            ],
            env=env,
        )
    except OSError:
        stop([node])
        raise
    return [node, sim], env


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    """Terminate the processes (kill any that does not end within 10 s)."""
    for proc in procs:
        proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def run_demo(
    domain: str,
    checkpoint: Path | None,
    episodes: int,
    rate: float,
    seed: int,
    out: Path,
    timeout: float,
    node_name: str = "ompn_node",
    params_file: Path | None = None,
    sim_params: Sequence[str] = (),
) -> int:
    """Launch, monitor and summarise a live run of ``checkpoint`` (none: the shipped checkpoint of
    ``domain``); returns 0, or 1 when no episode was observed."""
    checkpoint = checkpoint or shipped_checkpoint(domain)
    start = time.perf_counter()
    procs, env = launch(domain, checkpoint, rate, seed, episodes, node_name, params_file, sim_params)
    try:
        print(
            f"{domain}_sim and ompn_node running (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}); "
            f"segmenting {episodes} episodes live with {checkpoint}"
        )
        found = monitor(episodes, timeout, node_name)
    finally:
        stop(procs)
    if not found:
        print("no complete episode was observed", file=sys.stderr)
        return 1
    summary = summarise(found, out)
    print(
        f"\nonline segmentation over ROS 2: {summary['episodes']} episodes, "
        f"F1(tol=0) {summary['f1_tol0']:.3f}, F1(tol=1) {summary['f1_tol1']:.3f}, "
        f"alignment {summary['align_acc']:.3f}, "
        f"observation→boundary latency p50 {summary['latency_ms_p50']:.2f} ms, "
        f"p99 {summary['latency_ms_p99']:.2f} ms"
    )
    print(f"plot and summary in {out}/  ({time.perf_counter() - start:.1f} s)")
    return 0
