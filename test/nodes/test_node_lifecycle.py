"""ompn_node in-process: lifecycle transitions, outputs, bad-input fuzzing (DDS on loopback)."""

from __future__ import annotations

import gc
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("ompn_ros.model.streaming")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float32MultiArray, Int32  # noqa: E402

from ompn_interfaces.msg import SubtaskBoundary  # noqa: E402
from ompn_ros import layout  # noqa: E402
from ompn_ros.checkpoints import shipped_checkpoint  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings, save_detector_settings  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.ensemble import write_ensemble  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

OBS_DIM = 6
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "node", seed=3,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=3, slot_size=16)


class Harness:
    """A peer node that feeds the ompn_node and records its outputs, sharing one executor."""

    def __init__(self, ctx, node: OMPNNode) -> None:
        self.node = node
        self.peer = rclpy.create_node("peer", context=ctx)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(node)
        self.executor.add_node(self.peer)
        self.obs_pub = self.peer.create_publisher(Float32MultiArray, "observation", RELIABLE)
        self.js_pub = self.peer.create_publisher(JointState, "joint_states", RELIABLE)
        self.pi: list[np.ndarray] = []
        self.actions: list[int] = []
        self.boundaries: list[SubtaskBoundary] = []
        name = node.get_name()
        self.peer.create_subscription(Float32MultiArray, f"/{name}/pi", self._on_pi, RELIABLE)
        self.peer.create_subscription(Int32, "cmd_action", lambda m: self.actions.append(m.data), RELIABLE)
        events = QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        self.peer.create_subscription(SubtaskBoundary, f"/{name}/boundary", self.boundaries.append, events)

    def _on_pi(self, msg: Float32MultiArray) -> None:
        # one dimension over all n + 2 values (3 slots, the expected position, pi_end)
        assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [(layout.PI_LABEL, 5, 5)]
        self.pi.append(np.array(msg.data, dtype=np.float32))

    def pump(self, until: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
            if until():
                return True
        return until()

    def wait_matched(self, topic: str = "/observation") -> None:
        """Both directions discovered (a writer matched before its reader drops the first message)."""
        pub = self.js_pub if topic == "/joint_states" else self.obs_pub
        assert self.pump(
            lambda: (
                pub.get_subscription_count() > 0
                and self.node.count_publishers(topic) > 0
                and self.node.outputs.pubs["pi"].get_subscription_count() > 0
            )
        ), "discovery timed out"
        # endpoint matching can lag the graph: probe with empty (rejected) messages until one arrives
        seg = self.node.segmenter
        before = seg.rejected["empty"]
        for _ in range(50):
            if topic == "/joint_states":
                self.js_pub.publish(JointState())
            else:
                self.send([])
            if self.pump(lambda: seg.rejected["empty"] > before, timeout=0.1):
                break
        self.pump(lambda: False, timeout=0.1)
        self.probes = seg.rejected["empty"] - before

    def send(self, obs) -> None:
        self.obs_pub.publish(Float32MultiArray(data=[float(v) for v in obs]))


def make_node(ctx, ckpt: Path, **params) -> OMPNNode:
    overrides = [Parameter("checkpoint", value=str(ckpt))]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return OMPNNode(context=ctx, parameter_overrides=overrides)


def reference_pi(ckpt: Path, observations: np.ndarray) -> np.ndarray:
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig())
    rows = []
    for x in observations:
        so = seg.step(x).step_output
        rows.append(np.concatenate([so.pi, [so.expected_position, so.pi_end]]).astype(np.float32))
    return np.array(rows)


def test_configure_fails_on_mismatched_checkpoint_with_reason(ctx, ckpt: Path, tmp_path: Path) -> None:
    node = make_node(ctx, ckpt, obs_dim=OBS_DIM + 1)
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert f"obs_dim={OBS_DIM}" in node.last_error and str(OBS_DIM + 1) in node.last_error
    node.destroy_node()
    node = make_node(ctx, ckpt, action_type="continuous")
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert "action_type='discrete'" in node.last_error
    node.destroy_node()
    node = make_node(ctx, ckpt, domain="craft")
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert "domain 'craft'" in node.last_error
    node.destroy_node()
    node = make_node(ctx, tmp_path / "missing")
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert "not a directory" in node.last_error
    node.destroy_node()


def test_node_runs_an_ensemble_checkpoint(ctx, ckpt: Path, tmp_path: Path) -> None:
    torch.manual_seed(4)
    other = tmp_path / "other"
    save_checkpoint(other, OMPNPolicy(OMPNConfig(obs_dim=OBS_DIM, action_type="discrete", action_dim=3,
                                                 n_slots=3, slot_size=16)))
    write_ensemble(tmp_path / "ensemble", [ckpt, other])
    node = make_node(ctx, tmp_path / "ensemble")
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.last_error
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    h = Harness(ctx, node)
    h.wait_matched()
    obs = np.random.default_rng(7).normal(size=(10, OBS_DIM)).astype(np.float32)
    for x in obs:
        h.send(x)
    assert h.pump(lambda: len(h.pi) == 10 and len(h.actions) == 10)
    np.testing.assert_allclose(np.array(h.pi), reference_pi(tmp_path / "ensemble", obs), atol=1e-6)
    assert not np.allclose(np.array(h.pi), reference_pi(ckpt, obs), atol=1e-4)  # not just one member
    node.destroy_node()


def test_parameter_validation_rejects_bad_values(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt)
    result = node.set_parameters([Parameter("detector_mode", value="sideways")])[0]
    assert not result.successful and "mode" in result.reason
    result = node.set_parameters([Parameter("detector_high", value=1.5)])[0]
    assert not result.successful
    result = node.set_parameters([Parameter("obs_source", value="camera")])[0]
    assert not result.successful and "obs_source" in result.reason
    node.destroy_node()


def test_outputs_deactivate_and_resume(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, detector_high=0.3)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    h = Harness(ctx, node)
    h.wait_matched()
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(30, OBS_DIM)).astype(np.float32)
    for x in obs[:20]:
        h.send(x)
    assert h.pump(lambda: len(h.pi) == 20 and len(h.actions) == 20)
    expected = reference_pi(ckpt, obs)
    np.testing.assert_allclose(np.array(h.pi), expected[:20], atol=1e-6)

    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    for x in rng.normal(size=(5, OBS_DIM)):
        h.send(x)
    h.pump(lambda: False, timeout=0.5)
    assert len(h.pi) == 20 and node.segmenter.accepted == 20  # nothing stepped while inactive

    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    h.wait_matched()
    for x in obs[20:]:
        h.send(x)
    assert h.pump(lambda: len(h.pi) == 30)
    np.testing.assert_allclose(np.array(h.pi), expected, atol=1e-6)  # memory continued across
    node.destroy_node()


def test_fuzz_malformed_messages(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, warn_throttle=5.0)
    node.trigger_configure()
    node.trigger_activate()
    h = Harness(ctx, node)
    h.wait_matched()
    rng = np.random.default_rng(1)
    valid = rng.normal(size=(10, OBS_DIM)).astype(np.float32)
    sent = {"wrong_length": 0, "non_finite": 0, "empty": 0}
    n_bad = 2400
    for i in range(n_bad):
        kind = ("wrong_length", "non_finite", "empty")[i % 3]
        if kind == "wrong_length":
            h.send(rng.normal(size=int(rng.choice([1, OBS_DIM - 1, OBS_DIM + 1, 500]))))
        elif kind == "non_finite":
            x = rng.normal(size=OBS_DIM)
            x[rng.integers(OBS_DIM)] = rng.choice([np.nan, np.inf, -np.inf])
            h.send(x)
        else:
            h.send([])
        sent[kind] += 1
        if i % 50 == 49:  # stay below the node's input queue depth (KEEP_LAST 100 drops the oldest)
            h.pump(lambda i=i: node.segmenter.rejected_total == i + 1 + h.probes, timeout=10)
        if i % 600 == 0:
            h.send(valid[i // 600])
    assert h.pump(lambda: node.segmenter.rejected_total == n_bad + h.probes, timeout=20)
    sent["empty"] += h.probes
    for x in valid[4:]:
        h.send(x)
    assert h.pump(lambda: len(h.pi) == 10)
    counters = node.counters()
    assert counters["rejected"] == n_bad + h.probes and counters["accepted"] == 10
    assert {k: counters[f"rejected_{k}"] for k in sent} == sent
    np.testing.assert_allclose(np.array(h.pi), reference_pi(ckpt, valid), atol=1e-6)

    # the same counters reach /diagnostics
    diags: list[dict[str, str]] = []
    h.peer.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: diags.append({kv.key: kv.value for kv in m.status[0].values}),
        10,
    )
    node.publish_diagnostics()
    assert h.pump(lambda: bool(diags))
    assert diags[-1]["rejected"] == str(n_bad + h.probes) and diags[-1]["rejected_empty"] == str(
        sent["empty"]
    )
    node.destroy_node()


def test_joint_state_source_rejects_out_of_order_stamps(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, obs_source="joint_state", joint_fields=["position", "velocity"])
    node.trigger_configure()
    node.trigger_activate()
    h = Harness(ctx, node)
    h.wait_matched("/joint_states")
    rng = np.random.default_rng(2)
    obs = rng.normal(size=(6, OBS_DIM))
    stamps = [100, 200, 150, 200, 300, 250]  # 150, 200 (duplicate), 250 are out of order
    for x, s in zip(obs, stamps, strict=True):
        msg = JointState(name=["a", "b", "c"], position=x[:3].tolist(), velocity=x[3:].tolist())
        msg.header.stamp.sec, msg.header.stamp.nanosec = 0, s
        h.js_pub.publish(msg)
    assert h.pump(lambda: node.segmenter.accepted + node.segmenter.rejected_total == 6 + h.probes)
    assert node.segmenter.rejected["out_of_order_stamp"] == 3 and node.segmenter.accepted == 3
    assert h.pump(lambda: len(h.pi) == 3)
    np.testing.assert_allclose(
        np.array(h.pi), reference_pi(ckpt, obs[[0, 1, 4]].astype(np.float32)), atol=1e-6
    )
    node.destroy_node()


def test_cleanup_and_reconfigure_with_new_detector(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.segmenter.detector_config.high == 0.5
    assert gc.get_freeze_count() > 0 and gc.is_tracked(node.segmenter)  # configured: out of the collector
    assert not any(node.segmenter is o for o in gc.get_objects())  # frozen objects are not listed
    assert node.trigger_cleanup() == TransitionCallbackReturn.SUCCESS
    assert node.segmenter is None
    assert gc.get_freeze_count() == 0  # the old model can be collected again
    assert node.set_parameters([Parameter("detector_high", value=0.2),
                                Parameter("detector_hysteresis", value=0.05)])[0].successful
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.segmenter.detector_config.high == 0.2
    assert node.segmenter.detector_config.low_threshold == pytest.approx(0.15)
    node.destroy_node()


@pytest.mark.parametrize("name", ["ompn_node.yaml", "ompn_node_craft.yaml", "ompn_node_dial.yaml"])
def test_shipped_params_files_fit_the_node(ctx, ckpt: Path, name: str, tmp_path: Path) -> None:
    import yaml

    doc = yaml.safe_load((Path(__file__).resolve().parents[2] / "config" / name).read_text())
    params = doc["/**/ompn_node"]["ros__parameters"]
    domain = params.pop("domain", None)  # the test checkpoint is not a Craft/Dial model
    params.pop("checkpoint", None)
    if params.get("detector_mode") == "hsmm":  # decodes with the duration model of the checkpoint it runs
        ckpt = Path(shutil.copytree(ckpt, tmp_path / "ckpt"))
        shipped = load_detector_settings(shipped_checkpoint(domain))
        stored = DetectorSettings(online=shipped.online, duration_model=shipped.duration_model)
        save_detector_settings(ckpt, stored)
    node = make_node(ctx, ckpt, **params)  # wrong names/types/ranges raise here
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.last_error
    cfg = node.segmenter.detector_config
    given = {"detector_high": cfg.high, "detector_mode": cfg.mode,  # what a file sets, the node runs
             "detector_min_segment_length": cfg.min_segment_length,
             "detector_lag": getattr(node.segmenter.detector, "lag", 0)}
    assert {k: v for k, v in given.items() if k in params} == {k: params[k] for k in given if k in params}
    node.destroy_node()


def test_receive_stamps_stay_increasing_when_the_clock_stands_still(ctx, ckpt: Path) -> None:
    """Array input without message info (EventsExecutor) is stamped at reception; with sim time and
    no /clock the clock reads 0 for every message, and none may be rejected as out of order."""
    from ompn_ros.data.messages import encode_float32_array

    node = make_node(ctx, ckpt, use_sim_time=True)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    assert node.get_clock().now().nanoseconds == 0
    obs = np.random.default_rng(5).normal(size=(4, OBS_DIM)).astype(np.float32)
    for x in obs:
        node.inputs.on_array(encode_float32_array(x))
    node.inputs.on_array(b"\x00\x01\x00\x00garbage")  # undecodable: counted, never fatal
    seg = node.segmenter
    assert seg.accepted == 4 and seg.rejected["out_of_order_stamp"] == 0
    assert seg.rejected["malformed"] == 1
    node.destroy_node()


def test_a_late_boundary_subscriber_gets_the_last_event_only(ctx, ckpt: Path) -> None:
    """boundary_replay='last': TRANSIENT_LOCAL depth 1, not the whole history."""
    from episode_markers import marker

    from ompn_ros.data.messages import encode_float32_array

    node = make_node(ctx, ckpt)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    for _ in range(3):
        node.inputs.markers.on_episode(marker("start", sketch=""))
        for t in range(4):
            node.inputs.on_array(encode_float32_array(np.full(OBS_DIM, t, np.float32)))
        node.inputs.markers.on_episode(marker("end", steps="3"))
    assert node.counters()["boundaries"] >= 3
    h = Harness(ctx, node)  # subscribes ~/boundary TRANSIENT_LOCAL depth 1000 only now
    h.pump(lambda: len(h.boundaries) > 1, timeout=2.0)
    assert len(h.boundaries) == 1 and h.boundaries[0].final
    node.destroy_node()
