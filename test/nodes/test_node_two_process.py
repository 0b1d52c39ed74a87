"""Two processes over DDS: this test plays the sim, ``ompn_node`` runs as a subprocess.

sim (this process) -> observation/episode markers -> ompn_node (subprocess) -> ~/state, ~/pi,
~/boundary -> subscriber (this process).  Every field of the typed boundary events
(ompn_interfaces/SubtaskBoundary) and states (SubtaskState) must equal the offline replay of the same
StreamingSegmenter fed the stamps the node used, and the boundaries match the synthetic task's truth.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("ompn_ros.model.streaming")
trainer = pytest.importorskip("ompn_ros.train.trainer")
synthetic = pytest.importorskip("ompn_ros.train.synthetic")

from episode_markers import MarkerPublisher  # noqa: E402
from node_process import NodeProcess, Peer  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_interfaces.msg import SubtaskBoundary, SubtaskState  # noqa: E402
from ompn_ros import layout  # noqa: E402
from ompn_ros.data.messages import stamp_to_ns  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.metrics import mean_f1  # noqa: E402
from ompn_ros.model.streaming import StreamingPolicy  # noqa: E402
from ompn_ros.ros import containment  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402

torch.set_num_threads(1)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
EVENTS = QoSProfile(
    depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
HIGH = 0.2


def call(client, peer: Peer, srv_type, timeout: float = 10.0):
    """Call a service of the subprocess node from this process; None on time-out.  The clients are
    made when the test starts: Fast DDS drops a response whose client's response reader the service
    has not matched yet ("client will not receive response"), and ``wait_for_service`` sees only the
    request side, so a client made just before its call can lose the answer on a loaded machine (a
    ~/reset call did, once, in a full test run)."""
    if not client.wait_for_service(timeout_sec=timeout):
        return None
    future = client.call_async(srv_type.Request())
    peer.pump(future.done, timeout)
    return future.result() if future.done() else None


@pytest.mark.parametrize("executor", ["events", "single"])
def test_sim_node_subscriber(synthetic_checkpoint: Path, ros_env: dict[str, str], executor: str) -> None:
    from lifecycle_msgs.srv import GetState
    from std_srvs.srv import Trigger

    ckpt = synthetic_checkpoint
    ns = f"/tp_{os.getpid()}_{executor}"  # unique: the DDS domain may be shared with other test runs
    episodes = synthetic.make_dataset("discrete", 2, seed=900)
    proc = NodeProcess(
        ros_env, f"checkpoint:={ckpt}", f"detector_high:={HIGH}",
        # the whole detector, so that the checkpoint's own detector.json does not apply
        "detector_hysteresis:=0.0", "detector_min_segment_length:=1", "detector_mode:=falling_edge",
        "detector_force_first_step_low:=true", "diagnostics_period:=0.1", f"executor:={executor}", ns=ns,
    )  # fmt: skip
    peer = Peer(proc, name="fake_sim")
    try:
        sim = peer.node
        obs_pub = sim.create_publisher(Float32MultiArray, proc.topic(layout.OBSERVATION), RELIABLE)
        markers = MarkerPublisher(sim, ns, RELIABLE)
        get_state = sim.create_client(GetState, proc.topic("ompn_node/get_state"))
        reset_client = sim.create_client(Trigger, proc.topic("ompn_node/reset"))
        pis: list[np.ndarray] = []
        events: list[SubtaskBoundary] = []
        states: list[SubtaskState] = []
        diags = peer.statuses(proc.status_name)  # this node's status only (the domain may be shared)
        sim.create_subscription(
            Float32MultiArray, proc.topic("ompn_node/pi"), lambda m: pis.append(np.array(m.data)), RELIABLE
        )
        sim.create_subscription(SubtaskBoundary, proc.topic("ompn_node/boundary"), events.append, EVENTS)
        sim.create_subscription(SubtaskState, proc.topic("ompn_node/state"), states.append, RELIABLE)
        pump = peer.pump

        peer.wait_active(proc, 30)
        # start markers are idempotent before the first step: repeat until the node has seen one
        for _ in range(100):
            markers.publish(layout.EPISODE_START, {layout.KEY_SKETCH: ""})
            if pump(lambda: int(diags[-1]["episode_starts"]) >= 1, 0.2):
                break
        assert int(diags[-1]["episode_starts"]) >= 1 and obs_pub.get_subscription_count() > 0

        for i, ep in enumerate(episodes):
            if i > 0:
                markers.publish(layout.EPISODE_START, {layout.KEY_SKETCH: ""})
            start = len(pis)
            for t in range(ep.length + 1):  # the real steps and the final (done) observation
                obs_pub.publish(Float32MultiArray(data=ep.observations[t].tolist()))
                assert pump(lambda t=t, start=start: len(pis) == start + t + 1, 5), f"no ~/pi for step {t}"
            markers.publish(layout.EPISODE_END, {layout.KEY_STEPS: str(ep.length)})
            assert pump(lambda i=i: sum(e.final for e in events) == i + 1, 5)
        assert pump(lambda: len(states) == sum(ep.length + 1 for ep in episodes), 5)

        segmenter = StreamingSegmenter(StreamingPolicy.from_checkpoint(ckpt), DetectorConfig(high=HIGH))
        preds, state0 = [], 0
        for i, ep in enumerate(episodes):
            ep_states = states[state0 : state0 + ep.length + 1]
            state0 += ep.length + 1
            stamps = np.array([stamp_to_ns(st.header.stamp) for st in ep_states], dtype=np.int64)
            replay = replay_episode(segmenter, ep, include_done_step=True, stamps_ns=stamps)
            assert [(st.episode, st.step, st.header.frame_id) for st in ep_states] == [
                (i + 1, t, "") for t in range(ep.length + 1)]
            got_rows = np.array([[*st.pi, st.expected_position, st.pi_end] for st in ep_states[: ep.length]])
            want_rows = np.column_stack([replay.pi, replay.expected_position, replay.pi_end])
            np.testing.assert_allclose(got_rows, want_rows, rtol=0, atol=1e-5)
            got = [e for e in events if e.episode == i + 1]
            want = replay.published
            assert [(e.node, e.header.frame_id, e.step, e.subtask, e.subtask_id, e.memory_level,
                     e.decided_step, e.final, stamp_to_ns(e.header.stamp), stamp_to_ns(e.decided_stamp))
                    for e in got] == [
                (proc.topic("ompn_node"), "", b.step, b.subtask, -1, b.level, b.detected_at, b.final,
                 b.stamp_ns, int(stamps[b.detected_at])) for b in want]  # fmt: skip
            np.testing.assert_allclose([e.score for e in got], [b.score for b in want], rtol=1e-6)
            preds.append(np.array(sorted({e.step for e in got})))
            assert got[-1].step == ep.length - 1 and got[-1].final
        assert mean_f1(preds, [ep.boundaries for ep in episodes], tol=1).f1 >= 0.75
        # the node's services are served by its executor (lifecycle state, ~/reset)
        state = call(get_state, peer, GetState)
        assert state is not None and state.current_state.label == "active"
        pump(lambda: False, 0.5)  # let /diagnostics catch up with the last end marker's new episode
        starts_before = int(diags[-1]["episode_starts"])
        assert int(diags[-1]["episodes"]) == int(diags[-1]["episodes_ended"]) == len(episodes)
        reset = call(reset_client, peer, Trigger)
        assert reset is not None and reset.success, reset
        assert pump(lambda: int(diags[-1]["episode_starts"]) == starts_before + 1, 5)
    finally:
        peer.close()
        out = proc.stop()
    assert proc.returncode == 0, out
    assert "subtask boundary" in out
    assert "FATAL" not in out and "context is invalid" not in out and "Traceback" not in out
    assert not containment.problems()  # DDS stayed on loopback and shared memory
