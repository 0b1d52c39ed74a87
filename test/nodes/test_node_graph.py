"""ompn_node on a real graph (subprocesses over DDS on loopback): a BEST_EFFORT publisher, an
incompatible QoS reported by the node, two namespaced nodes, a live parameter change, sim time from a
/clock this test publishes (a clock that jumps back), SIGINT and a bad start-up parameter."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from episode_markers import MarkerPublisher  # noqa: E402
from node_process import NodeProcess, Peer, node_command  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_interfaces.msg import SubtaskBoundary  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402

OBS_DIM = 6
ROOT = Path(__file__).resolve().parents[2]
BEST_EFFORT = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATE = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "graph", seed=11,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=3, slot_size=16)


def start_node(ckpt: Path, env: dict[str, str], *params: str, ns: str = "/") -> NodeProcess:
    return NodeProcess(env, f"checkpoint:={ckpt}", "diagnostics_period:=0.1", "detector_high:=0.3", *params,
                       ns=ns)  # fmt: skip


def stop(proc: NodeProcess) -> str:
    """SIGINT, then the node's whole output; it must end cleanly (no FATAL from a timer)."""
    out = proc.stop()
    assert proc.returncode == 0, out
    assert "FATAL" not in out and "context is invalid" not in out and "Traceback" not in out, out
    return out


class GraphPeer(Peer):
    """This process's side of the graph, able to set the nodes' parameters."""

    def __init__(self, procs: list[NodeProcess]) -> None:
        super().__init__(*procs, name="graph_peer")

    def set_param(self, node: str, name: str, value: object) -> object:
        client = self.node.create_client(SetParameters, f"{node}/set_parameters")
        assert client.wait_for_service(timeout_sec=20)
        if isinstance(value, float):
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        else:
            pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(value))
        future = client.call_async(SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
        assert self.pump(future.done, 10)
        return future.result().results[0]


def test_best_effort_publisher_namespaced_nodes_qos_report_and_live_parameters(
    ckpt: Path, ros_env: dict[str, str]
) -> None:
    r1, r2 = f"r1_{os.getpid()}", f"r2_{os.getpid()}"  # unique: the DDS domain may be shared
    procs = [start_node(ckpt, ros_env, ns=f"/{r1}"),
             start_node(ckpt, ros_env, "obs_qos:=reliable", ns=f"/{r2}")]
    peer = GraphPeer(procs)
    outputs = []
    try:
        pis: dict[str, list] = {r1: [], r2: []}
        pubs = {}
        for ns in pis:
            pubs[ns] = peer.node.create_publisher(Float32MultiArray, f"/{ns}/observation", BEST_EFFORT)
            peer.node.create_subscription(Float32MultiArray, f"/{ns}/ompn_node/pi",
                                          lambda msg, ns=ns: pis[ns].append(msg.data), RELIABLE)
        names = (f"/{r1}/ompn_node: segmenter", f"/{r2}/ompn_node: segmenter")
        assert peer.pump(lambda: all(peer.statuses(n) for n in names), 60), names
        obs = np.random.default_rng(0).normal(size=(40, OBS_DIM)).astype(np.float32)
        sent = 0
        while not pis[r1] and sent < len(obs):  # a BEST_EFFORT writer drops what it sends before matching
            for ns in pubs:
                pubs[ns].publish(Float32MultiArray(data=obs[sent].tolist()))
            sent += 1
            peer.pump(lambda: bool(pis[r1]), 0.5)
        pubs[r1].publish(b"")  # a 0-byte message (dropped by Fast DDS on the way) holds nothing back
        for x in obs[sent:sent + 10]:
            pubs[r1].publish(Float32MultiArray(data=x.tolist()))
            pubs[r2].publish(Float32MultiArray(data=x.tolist()))
        assert peer.pump(lambda: len(pis[r1]) >= 11, 10), len(pis[r1])
        assert pis[r2] == []  # RELIABLE subscription, BEST_EFFORT publisher: nothing matches
        assert peer.pump(lambda: int(peer.last(names[1]).get("qos_incompatible", 0)) >= 1, 10)
        assert peer.last(names[0])["qos_incompatible"] == "0"

        ok = peer.set_param(f"/{r1}/ompn_node", "detector_high", 0.25)
        assert ok.successful, ok.reason
        refused = peer.set_param(f"/{r1}/ompn_node", "checkpoint", "/elsewhere")
        assert not refused.successful and "'checkpoint'" in refused.reason and "configure" in refused.reason
        refused = peer.set_param(f"/{r1}/ompn_node", "detector_high", 2.0)
        assert not refused.successful and "detector_high" in refused.reason
    finally:
        peer.close()
        outputs = [stop(p) for p in procs]
    assert "detector now DetectorConfig(high=0.25" in outputs[0]
    qos_lines = [line for line in outputs[1].splitlines() if "incompatible" in line]
    assert qos_lines and "obs_qos" in qos_lines[0] and "RELIABILITY" in qos_lines[0]


def test_sim_time_stamps_outputs_and_a_clock_jump_back_starts_a_new_episode(
    ckpt: Path, ros_env: dict[str, str]
) -> None:
    sim = f"sim_{os.getpid()}"
    proc = start_node(ckpt, ros_env, "use_sim_time:=true", ns=f"/{sim}")
    peer = GraphPeer([proc])
    try:
        clock = peer.node.create_publisher(Clock, "/clock", 10)
        obs_pub = peer.node.create_publisher(Float32MultiArray, f"/{sim}/observation", RELIABLE)
        markers = MarkerPublisher(peer.node, f"/{sim}", RELIABLE)
        events: list[SubtaskBoundary] = []
        peer.node.create_subscription(SubtaskBoundary, f"/{sim}/ompn_node/boundary", events.append, LATE)
        pis: list = []
        peer.node.create_subscription(Float32MultiArray, f"/{sim}/ompn_node/pi", pis.append, RELIABLE)
        name = f"/{sim}/ompn_node: segmenter"
        t0 = 1_000 * 1_000_000_000

        ticked = [t0]

        def tick(ns: int) -> None:
            clock.publish(m.encode_clock(ns))  # the codec's bytes, published raw
            ticked[0] = ns

        def advance() -> bool:  # 1 ms of sim time per pump: the node's sim-time timer keeps firing, so
            tick(ticked[0] + 1_000_000)  # a /diagnostics sent before the peer matched is not the only one
            return bool(peer.stamps(name)) and t0 <= peer.stamps(name)[-1] <= ticked[0]

        assert peer.pump(advance, 60), "node never followed /clock"
        t0 = ticked[0]  # the steps below continue from the clock's last tick
        for _ in range(50):  # markers are idempotent before the first step: repeat until seen
            markers.publish("start", {"sketch": ""})
            if peer.pump(lambda: int(peer.last(name)["episode_starts"]) >= 1, 0.2):
                break
        assert peer.pump(lambda: obs_pub.get_subscription_count() > 0, 20)
        peer.pump(lambda: False, 0.5)  # the reader side matches too
        rng = np.random.default_rng(1)
        for t in range(8):  # /diagnostics runs on sim time too: progress is read from ~/pi
            tick(t0 + (t + 1) * 40_000_000)
            peer.pump(lambda: False, 0.05)
            obs_pub.publish(Float32MultiArray(data=rng.normal(size=OBS_DIM).tolist()))
            assert peer.pump(lambda t=t: len(pis) == t + 1, 10), peer.last(name)
        markers.publish("end", {"steps": "7"})
        assert peer.pump(lambda: any(e.final for e in events), 10)
        for event in events:  # sim time, not wall time
            assert t0 < m.stamp_to_ns(event.header.stamp) <= m.stamp_to_ns(event.decided_stamp) < t0 + 10**9

        for k in range(2):  # the next episode begins (the end marker closed the last one) ...
            tick(t0 + 2 * 10**9 + k * 40_000_000)
            peer.pump(lambda: False, 0.05)
            obs_pub.publish(Float32MultiArray(data=rng.normal(size=OBS_DIM).tolist()))
            assert peer.pump(lambda k=k: len(pis) == 9 + k, 10)
        restart = iter(range(5 * 10**9, 10**12, 50_000_000))  # ... and the sim restarts: its clock is at 5 s
        assert peer.pump(lambda: (tick(next(restart)), peer.stamps(name)[-1] < 10**10)[1], 20)
        obs_pub.publish(Float32MultiArray(data=rng.normal(size=OBS_DIM).tolist()))
        assert peer.pump(lambda: len(pis) == 11, 10)
        assert peer.pump(lambda: (tick(next(restart)), peer.last(name)["accepted"] == "11")[1], 20)
        counters = peer.last(name)
        assert counters["rejected"] == "0" and counters["clock_jumps"] == "1" and counters["episodes"] == "3"
    finally:
        peer.close()
        stop(proc)


@pytest.mark.parametrize(
    ("module", "param"),
    [("ompn_ros.nodes.ompn_node", "detector_high:=2.0"), ("ompn_ros.nodes.ompn_node", "obs_qos:=fast"),
     ("ompn_ros.nodes.episode_monitor", "timeout:=-1.0"), ("ompn_ros.nodes.dds_probe", "count:=0")],
)
def test_invalid_start_up_parameter_exits_2_with_one_line(module: str, param: str,
                                                          ros_env: dict[str, str]) -> None:
    cmd = node_command(param, module=module)
    proc = subprocess.run(cmd, env=ros_env, cwd=str(ROOT), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and param.split(":=")[0] in lines[0] and "Traceback" not in proc.stderr, lines


def test_diagnostics_keep_their_rate_under_interleaved_clocks(ckpt: Path, ros_env: dict[str, str]) -> None:
    """Two sims' clocks on one /clock (100 s apart, alternating): a use_sim_time node still sends
    /diagnostics once per diagnostics_period of real time, not at every forward jump."""
    sim = f"mix_{os.getpid()}"
    proc = start_node(ckpt, ros_env, "use_sim_time:=true", "diagnostics_period:=0.5", ns=f"/{sim}")
    peer = GraphPeer([proc])
    try:
        clock = peer.node.create_publisher(Clock, "/clock", 10)
        name = f"/{sim}/ompn_node: segmenter"
        ticks = iter(range(10**9))

        def interleave() -> bool:
            k = next(ticks)
            clock.publish(m.encode_clock((900 + 100 * (k % 2)) * 10**9 + (k // 2) * 10_000_000))
            return False

        assert peer.pump(lambda: interleave() or bool(peer.statuses(name)), 60), "no /diagnostics"
        before, start = len(peer.statuses(name)), time.monotonic()
        peer.pump(interleave, 4.0)
        sent = len(peer.statuses(name)) - before
        elapsed = time.monotonic() - start
        assert 2 <= sent <= elapsed / 0.5 + 3, (sent, elapsed, next(ticks))
    finally:
        peer.close()
        out = stop(proc)
    assert "Traceback" not in out
