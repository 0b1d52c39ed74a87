"""ompn_node: lifecycle ROS 2 node that runs the OMPN online on every observation.

A thin wrapper around :class:`ompn_ros.segmenter.StreamingSegmenter`.

Subscriptions (while active; names from :mod:`ompn_ros.layout`, relative to the namespace):
    ``observation``   Float32MultiArray (``obs_source='array'``), or ``joint_states`` JointState
                      (``obs_source='joint_state'``: the ``joint_fields`` arrays concatenated).
    ``episode``       DiagnosticArray episode marker: 'start' resets the memory (sketch from the
                      marker, else the latest ``sketch`` message, else the ``sketch`` parameter);
                      'end' closes the last segment at step ``steps - 1``.
    ``sketch``        Int32MultiArray: sketch of the coming episode (resets again if no step yet).
Service: ``~/reset`` (std_srvs/Trigger) starts a new episode.

Publications (per accepted observation):
    ``cmd_action``    Int32 (discrete: argmax env action, or ``action_dim`` = 'done' when
                      π_end > ``done_threshold``) or Float32MultiArray (continuous: Gaussian mean).
    ``~/pi``          Float32MultiArray, ``layout.dim=[('slot', n, n)]``, ``data`` = the n slot
                      probabilities π_1..π_n (lowest slot first), then the expected position
                      Σ i·π_i (paper π_avg), then π_end: n + 2 values.
    ``~/boundary``    DiagnosticArray (RELIABLE + TRANSIENT_LOCAL, depth 1000), one status named
                      '<node>/subtask_boundary' with keys step, subtask, score, level,
                      detected_at, stamp_ns, final; ``header.stamp`` = the boundary step's stamp.
    ``/diagnostics``  periodic DiagnosticArray with the node's counters (accepted, rejected by
                      reason, episodes, boundaries).
Bad observations (wrong length, NaN/Inf, empty, out-of-order stamps) are skipped without
stepping the model, counted, and reported with a throttled warning.

Stamps: JointState input uses ``header.stamp``.  Array input uses the publisher's DDS source
timestamp from the message info with ``executor='single'``; the EventsExecutor cannot deliver
message info in rclpy 7.1.6 ("SystemError: null argument to internal routine"), so with it the
node stamps array input with its own clock at reception.

Hot path: the observation subscription is ``raw=True`` (the float32 data is read straight from the
CDR bytes) and the action and ``~/pi`` are published as pre-encoded CDR; the boundary event goes
out before them.

Executor: ``executor='events'`` (default) = ``rclpy.experimental.EventsExecutor``, measured here
to cut the observation -> boundary latency by ~0.4-0.5 ms against ``'single'`` =
``SingleThreadedExecutor`` (BENCHMARKS.md).  Its ``spin()`` serves nothing in rclpy 7.1.6, so
:func:`spin_until_shutdown` drives it with ``spin_once``, which works (lifecycle and parameter
services included).  ``'single'`` stays available should the experimental executor misbehave.
"""

from __future__ import annotations

import array
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray
from std_srvs.srv import Trigger

from ompn_ros import layout
from ompn_ros.data.messages import (
    encode_diagnostic_status,
    encode_float32_array,
    encode_int32,
    parse_float32_array,
)
from ompn_ros.detect.online import MODES, BoundaryEvent, DetectorConfig, DetectorConfigError
from ompn_ros.segmenter import InvalidInput, MalformedMessage, SketchError, StreamingSegmenter

NODE_NAME = "ompn_node"
BOUNDARY_QOS_DEPTH = 1000
OBS_SOURCES = ("array", "joint_state")
EXECUTORS = ("single", "events")
JOINT_FIELDS = ("position", "velocity", "effort")


class NodeConfigError(ValueError):
    """A parameter or the checkpoint does not fit; the message is the transition's failure reason."""


def default_checkpoint(domain: str) -> Path | None:
    """The checkpoint shipped as package data for ``domain`` (``ompn_ros/checkpoints/<domain>``)."""
    from ompn_ros.checkpoints import MissingCheckpointError, shipped_checkpoint

    try:
        return shipped_checkpoint(domain)
    except MissingCheckpointError:
        return None


def load_policy(path: str) -> Any:
    """The streaming stepper of a checkpoint directory, OMPN or LSTM (safetensors + JSON, never pickle)."""
    from ompn_ros.model.factory import stepper_from_checkpoint

    return stepper_from_checkpoint(path)


def _desc(
    text: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    ints: bool = False,
    read_only: bool = False,
) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=text, read_only=read_only)
    if lo is not None and hi is not None:
        if ints:
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            desc.floating_point_range = [
                FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
            ]
    return desc


class OMPNNode(LifecycleNode):
    """Lifecycle node: configure = load + validate the checkpoint, activate = subscribe and run."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.declare_parameter(
            "domain", "", _desc("'craft' | 'dial' | '' (checks sizes, picks the default checkpoint)")
        )
        self.declare_parameter(
            "checkpoint", "",
            _desc("checkpoint directory, or an ensemble directory (ensemble.json); '' = the shipped one "
                  "for 'domain'"),
        )
        self.declare_parameter("obs_source", "array", _desc("'array' (observation topic) | 'joint_state'"))
        self.declare_parameter(
            "joint_fields", ["position"], _desc("JointState arrays concatenated into the observation")
        )
        self.declare_parameter(
            "obs_dim",
            0,
            _desc("expected observation size (0 = from domain/checkpoint)", lo=0, hi=1_000_000, ints=True),
        )
        self.declare_parameter(
            "action_type", "", _desc("expected action type: 'discrete' | 'continuous' | '' (any)")
        )
        self.declare_parameter(
            "sketch_mode", "", _desc("expected model sketch mode: 'none' | 'sum' | '' (any)")
        )
        self.declare_parameter(
            "sketch", [-1], _desc("default sketch (subtask ids) for sketch models; [-1] = none")
        )
        self.declare_parameter(
            "detector_high", 0.5, _desc("a boundary run starts when the score > high", lo=0.0, hi=1.0)
        )
        self.declare_parameter(
            "detector_hysteresis", 0.0, _desc("run ends when score <= high - hysteresis", lo=0.0, hi=1.0)
        )
        self.declare_parameter(
            "detector_min_segment_length",
            1,
            _desc("minimum steps per detected segment", lo=1, hi=100_000, ints=True),
        )
        self.declare_parameter("detector_mode", "falling_edge", _desc(f"one of {MODES}"))
        self.declare_parameter("detector_force_first_step_low", True, _desc("treat step 0's score as 0"))
        self.declare_parameter(
            "done_threshold",
            0.5,
            _desc("discrete: publish done (= action_dim) when pi_end exceeds this", lo=0.0, hi=1.0),
        )
        self.declare_parameter(
            "auto_start", True, _desc("configure and activate at start-up", read_only=True)
        )
        self.declare_parameter(
            "qos_depth",
            100,
            _desc("depth of the input and per-step output queues", lo=1, hi=100_000, ints=True),
        )
        self.declare_parameter(
            "diagnostics_period", 1.0, _desc("seconds between /diagnostics messages", lo=0.01, hi=3600.0)
        )
        self.declare_parameter(
            "warn_throttle", 1.0, _desc("seconds between bad-input warnings", lo=0.0, hi=3600.0)
        )
        self.declare_parameter("executor", "events", _desc(f"one of {EXECUTORS}", read_only=True))
        self.declare_parameter("torch_threads", 1, _desc("torch intra-op threads", lo=1, hi=64, ints=True))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.segmenter: StreamingSegmenter | None = None
        self.last_error = ""
        self.boundaries_published = 0
        self.last_stamp_ns = 0
        self._last_receive_ns = 0
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._service: Any = None
        self._timer: Any = None
        self._latest_sketch: np.ndarray | None = None
        self._last_warn = 0.0
        self._status_name = f"{self.get_name()}/subtask_boundary"
        self._n_slots = 0
        self._active = False
        self._done_threshold = 0.5

    # --- parameters ----------------------------------------------------------------------------
    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        try:
            self._detector_config(values)
            if "obs_source" in values and values["obs_source"] not in OBS_SOURCES:
                raise NodeConfigError(
                    f"obs_source must be one of {OBS_SOURCES}, got {values['obs_source']!r}"
                )
            if "joint_fields" in values:
                bad = [f for f in values["joint_fields"] if f not in JOINT_FIELDS]
                if bad or not values["joint_fields"]:
                    raise NodeConfigError(
                        f"joint_fields must be a non-empty subset of {JOINT_FIELDS}, "
                        f"got {values['joint_fields']}"
                    )
            for key, allowed in (
                ("action_type", ("", "discrete", "continuous")),
                ("sketch_mode", ("", "none", "sum")),
                ("domain", ("", *layout.DOMAINS)),
                ("executor", EXECUTORS),
            ):
                if key in values and values[key] not in allowed:
                    raise NodeConfigError(f"{key} must be one of {allowed}, got {values[key]!r}")
        except (NodeConfigError, DetectorConfigError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _param(self, name: str, overrides: dict[str, Any] | None = None) -> Any:
        if overrides and name in overrides:
            return overrides[name]
        return self.get_parameter(name).value

    def _detector_config(self, overrides: dict[str, Any] | None = None) -> DetectorConfig:
        high = float(self._param("detector_high", overrides))
        hysteresis = float(self._param("detector_hysteresis", overrides))
        return DetectorConfig(
            high=high,
            low=max(0.0, high - hysteresis),
            min_segment_length=int(self._param("detector_min_segment_length", overrides)),
            mode=str(self._param("detector_mode", overrides)),
            force_first_step_low=bool(self._param("detector_force_first_step_low", overrides)),
        )

    def _default_sketch(self) -> np.ndarray | None:
        values = [int(v) for v in self.get_parameter("sketch").value]
        # [-1] means "no default sketch": 0 is a valid id (Dial digit 0), and ROS cannot declare an
        # empty integer array.
        return np.asarray(values, dtype=np.int64) if values and values != [-1] else None

    def _resolve_checkpoint(self) -> str:
        path = str(self.get_parameter("checkpoint").value)
        domain = str(self.get_parameter("domain").value)
        if path:
            if not Path(path).is_dir():
                raise NodeConfigError(f"checkpoint '{path}' is not a directory")
            return path
        if not domain:
            raise NodeConfigError(
                "no checkpoint: set the 'checkpoint' parameter or 'domain' for the shipped one"
            )
        found = default_checkpoint(domain)
        if found is None:
            raise NodeConfigError(
                f"no shipped checkpoint for domain '{domain}'; set the 'checkpoint' parameter"
            )
        return str(found)

    def _validate_model(self, config: Any) -> None:
        domain = str(self.get_parameter("domain").value)
        expected_dim = int(self.get_parameter("obs_dim").value)
        expected_action = str(self.get_parameter("action_type").value)
        if domain:
            dom = layout.DOMAINS[domain]
            if self.get_parameter("obs_source").value == "array":
                expected_dim = expected_dim or dom.obs_dim
            expected_action = expected_action or dom.action_type
            if config.action_dim != dom.action_dim:
                raise NodeConfigError(
                    f"checkpoint action_dim={config.action_dim} does not fit domain '{domain}' "
                    f"(action_dim={dom.action_dim})"
                )
        if expected_dim and config.obs_dim != expected_dim:
            raise NodeConfigError(
                f"checkpoint obs_dim={config.obs_dim} does not match the expected observation size "
                f"{expected_dim}"
            )
        if expected_action and config.action_type != expected_action:
            raise NodeConfigError(
                f"checkpoint action_type='{config.action_type}' does not match the expected "
                f"'{expected_action}'"
            )
        sketch_mode = str(self.get_parameter("sketch_mode").value)
        if sketch_mode and config.sketch_mode != sketch_mode:
            raise NodeConfigError(
                f"checkpoint sketch_mode='{config.sketch_mode}' does not match the expected '{sketch_mode}'"
            )

    # --- lifecycle -----------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except Exception as exc:
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"configure failed: {self.last_error}")
            self.segmenter = None
            return TransitionCallbackReturn.FAILURE
        self.last_error = ""
        return TransitionCallbackReturn.SUCCESS

    def _configure(self) -> None:
        import torch

        torch.set_num_threads(int(self.get_parameter("torch_threads").value))
        path = self._resolve_checkpoint()
        policy = load_policy(path)
        self._validate_model(policy.config)
        detector = self._detector_config()
        segmenter = StreamingSegmenter(policy, detector)
        if segmenter.needs_sketch and self._default_sketch() is not None:
            segmenter.reset(self._default_sketch())
        self.segmenter = segmenter
        self._done_threshold = float(self.get_parameter("done_threshold").value)
        n = int(policy.config.n_slots)
        self._n_slots = n
        depth = int(self.get_parameter("qos_depth").value)
        per_step = QoSProfile(
            depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
        )
        events = QoSProfile(
            depth=BOUNDARY_QOS_DEPTH,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            history=HistoryPolicy.KEEP_LAST,
        )
        action_type = Int32 if policy.config.action_type == "discrete" else Float32MultiArray
        self._pubs = {
            "action": self.create_lifecycle_publisher(action_type, layout.CMD_ACTION, per_step),
            "pi": self.create_lifecycle_publisher(Float32MultiArray, layout.PI, per_step),
            "boundary": self.create_lifecycle_publisher(DiagnosticArray, layout.BOUNDARY, events),
            "diagnostics": self.create_lifecycle_publisher(DiagnosticArray, layout.DIAGNOSTICS, 10),
        }
        self.get_logger().info(
            f"configured: checkpoint={path} obs_dim={policy.config.obs_dim} n_slots={n} "
            f"action={policy.config.action_type} sketch_mode={policy.config.sketch_mode} detector={detector}"
        )

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.segmenter is None:
            self.last_error = "activate without a configured segmenter"
            return TransitionCallbackReturn.FAILURE
        depth = int(self.get_parameter("qos_depth").value)
        inputs = QoSProfile(
            depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
        )
        markers = QoSProfile(
            depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
        )
        # Markers first: when a marker and an observation are both ready, the executor serves the
        # subscriptions in creation order, so the 'start' reset precedes the episode's first step.
        self._subs.append(
            self.create_subscription(DiagnosticArray, layout.EPISODE, self._on_episode, markers)
        )
        self._subs.append(self.create_subscription(Int32MultiArray, layout.SKETCH, self._on_sketch, markers))
        if self.get_parameter("obs_source").value == "joint_state":
            self._subs.append(
                self.create_subscription(JointState, layout.JOINT_STATES, self._on_joint_state, inputs)
            )
        else:  # raw CDR: the float32 data is read in place, no message object is built
            callback = self._on_array_info if self.uses_message_info else self._on_array
            self._subs.append(
                self.create_subscription(Float32MultiArray, layout.OBSERVATION, callback, inputs, raw=True)
            )
        self._service = self.create_service(Trigger, "~/reset", self._on_reset)
        self._timer = self.create_timer(
            float(self.get_parameter("diagnostics_period").value), self.publish_diagnostics
        )
        self._active = True
        self.get_logger().info("activated")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        self.get_logger().info("deactivated")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        for pub in self._pubs.values():
            self.destroy_lifecycle_publisher(pub)
        self._pubs = {}
        self.segmenter = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        return TransitionCallbackReturn.SUCCESS

    def _teardown_inputs(self) -> None:
        self._active = False
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        if self._service is not None:
            self.destroy_service(self._service)
            self._service = None
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None

    @property
    def uses_message_info(self) -> bool:
        """Array input takes its stamp from the DDS source timestamp (needs message info)."""
        return (
            self.get_parameter("obs_source").value == "array"
            and self.get_parameter("executor").value != "events"
        )

    # --- callbacks -----------------------------------------------------------------------------
    def _on_array_info(self, raw: bytes, info: dict[str, Any]) -> None:
        self._on_raw_array(raw, int(info["source_timestamp"]))

    def _on_array(self, raw: bytes) -> None:
        # The EventsExecutor cannot pass message info: stamp with the receive time instead, kept
        # strictly increasing (reception order is delivery order; a clock that stands still, e.g.
        # sim time between /clock ticks, must not turn into out-of-order rejections).
        stamp = max(self.get_clock().now().nanoseconds, self._last_receive_ns + 1)
        self._last_receive_ns = stamp
        self._on_raw_array(raw, stamp)

    def _on_raw_array(self, raw: bytes, stamp_ns: int) -> None:
        try:
            data = parse_float32_array(raw)
        except Exception as exc:  # any undecodable message is counted, never fatal
            if self.segmenter is not None and self._active:
                error = MalformedMessage(f"undecodable Float32MultiArray ({len(raw)} bytes): {exc}")
                self.segmenter.count_rejection(error)
                self._warn_throttled(f"skipped observation ({error.reason}): {error}")
            return
        self.process_observation(data, stamp_ns)

    def _on_joint_state(self, msg: JointState) -> None:
        fields = self.get_parameter("joint_fields").value
        parts = [np.asarray(getattr(msg, f), dtype=np.float32) for f in fields]
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        self.process_observation(np.concatenate(parts) if parts else np.zeros(0, np.float32), stamp)

    def process_observation(self, data: Any, stamp_ns: int | None) -> None:
        """Step the segmenter on one observation and publish its outputs (or count a rejection)."""
        seg = self.segmenter
        if seg is None or not self._active:
            return
        try:
            obs = (
                np.frombuffer(data, dtype=np.float32)
                if isinstance(data, array.array) and data.typecode == "f"
                else data
            )
            out = seg.step(obs, stamp_ns)
        except InvalidInput as exc:
            self._warn_throttled(f"skipped observation ({exc.reason}): {exc}")
            return
        self.last_stamp_ns = 0 if stamp_ns is None else int(stamp_ns)
        # The boundary event goes out first: it is the latency-critical product of this node
        # (logged after the per-step outputs, which must not wait for the console).
        if out.boundary is not None:
            self.publish_boundary(out.boundary, log=False)
        so = out.step_output
        # Pre-encoded CDR (same bytes as the message classes would give, without building them).
        if seg.policy.config.action_type == "discrete":
            done = so.done_prob > self._done_threshold
            self._pubs["action"].publish(encode_int32(seg.policy.config.action_dim if done else so.action))
        else:
            self._pubs["action"].publish(encode_float32_array(so.action, "action"))
        pi_values = np.empty(self._n_slots + 2, np.float32)
        pi_values[: self._n_slots] = so.pi
        pi_values[self._n_slots] = so.expected_position
        pi_values[self._n_slots + 1] = so.pi_end
        self._pubs["pi"].publish(encode_float32_array(pi_values, "slot", self._n_slots))
        if out.boundary is not None:
            self.log_boundary(out.boundary)

    def publish_boundary(self, event: BoundaryEvent, log: bool = True) -> None:
        """Publish ``event`` on ``~/boundary`` (CDR built directly) and, with ``log``, log it."""
        stamp = event.stamp_ns or self.get_clock().now().nanoseconds
        values = {
            "step": event.step,
            "subtask": event.subtask,
            "score": f"{event.score:.6f}",
            "level": event.level,
            "detected_at": event.detected_at,
            "stamp_ns": event.stamp_ns,
            "final": "true" if event.final else "false",
        }
        self._pubs["boundary"].publish(
            encode_diagnostic_status(stamp, self._status_name, "boundary", values, DiagnosticStatus.OK[0])
        )
        self.boundaries_published += 1
        if log:
            self.log_boundary(event)

    def log_boundary(self, event: BoundaryEvent) -> None:
        self.get_logger().info(
            f"subtask boundary: step={event.step} subtask={event.subtask} score={event.score:.3f} "
            f"level={event.level} detected_at={event.detected_at}{' (episode end)' if event.final else ''}"
        )

    def _warn_throttled(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn >= float(self.get_parameter("warn_throttle").value):
            self._last_warn = now
            total = self.segmenter.rejected_total if self.segmenter else 0
            self.get_logger().warning(f"{text} [{total} rejected so far]")

    def _start_episode(self, sketch: np.ndarray | None) -> bool:
        seg = self.segmenter
        if seg is None:
            return False
        if sketch is None or sketch.size == 0:
            sketch = self._latest_sketch if self._latest_sketch is not None else self._default_sketch()
        try:
            seg.reset(sketch)
        except SketchError as exc:
            self._warn_throttled(f"episode start ignored: {exc}")
            return False
        return True

    def _on_episode(self, msg: DiagnosticArray) -> None:
        from ompn_ros.data.messages import parse_sketch_value

        for status in msg.status:
            if status.name != layout.EPISODE_STATUS_NAME:
                continue
            values = {kv.key: kv.value for kv in status.values}
            if status.message == layout.EPISODE_START:
                try:
                    sketch = parse_sketch_value(values.get(layout.KEY_SKETCH, ""))
                except ValueError:
                    sketch = None
                self._latest_sketch = sketch if sketch is not None and sketch.size else None
                self._start_episode(sketch)
            elif status.message == layout.EPISODE_END and self.segmenter is not None and self.segmenter.ready:
                try:
                    steps = int(values.get(layout.KEY_STEPS, ""))
                except ValueError:
                    steps = 0
                final = self.segmenter.end_episode(steps - 1 if steps > 0 else None)
                if final is not None:
                    self.publish_boundary(final)
                self._start_episode(None)  # observations before the next start marker: new episode

    def _on_sketch(self, msg: Int32MultiArray) -> None:
        sketch = np.asarray(msg.data, dtype=np.int64)
        if sketch.size == 0:
            return
        self._latest_sketch = sketch
        seg = self.segmenter
        if seg is not None and (not seg.ready or seg.step_index < 0):
            self._start_episode(sketch)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = self._start_episode(None)
        response.message = "memory reset" if response.success else "reset failed (no segmenter or no sketch)"
        return response

    def counters(self) -> dict[str, int]:
        """The node's health counters (also published on /diagnostics)."""
        seg = self.segmenter
        out = {"accepted": 0, "rejected": 0, "episodes": 0, "boundaries": self.boundaries_published}
        if seg is not None:
            out.update(accepted=seg.accepted, rejected=seg.rejected_total, episodes=seg.episodes)
            out.update({f"rejected_{k}": int(v) for k, v in seg.rejected.items()})
        return out

    def publish_diagnostics(self) -> None:
        if "diagnostics" not in self._pubs:
            return
        counters = self.counters()
        level = DiagnosticStatus.WARN if counters["rejected"] else DiagnosticStatus.OK
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [
            DiagnosticStatus(
                level=level,
                name=f"{self.get_name()}: segmenter",
                message="rejected input" if counters["rejected"] else "ok",
                hardware_id="",
                values=[KeyValue(key=k, value=str(v)) for k, v in counters.items()],
            )
        ]
        self._pubs["diagnostics"].publish(msg)


def make_executor(kind: str, context: Any = None) -> Any:
    """``'events'``: the C++ ``rclpy.experimental.EventsExecutor``; ``'single'``: SingleThreadedExecutor."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def spin_until_shutdown(executor: Any, context: Any = None, period: float = 0.1) -> None:
    """Serve callbacks until the context shuts down (SIGINT/SIGTERM, ``rclpy.shutdown``).

    A ``spin_once`` loop rather than ``spin()``: the EventsExecutor's ``spin()`` in rclpy 7.1.6
    serves no callback and ignores SIGINT, while its ``spin_once`` works (module docstring).
    """
    while rclpy.ok(context=context):
        executor.spin_once(timeout_sec=period)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ompn_node``: configure + activate (``auto_start``), then spin."""
    rclpy.init(args=args)
    node = OMPNNode()
    code = 0
    executor = None
    try:
        if node.get_parameter("auto_start").value:
            node.trigger_configure()
            if node.segmenter is None:
                node.get_logger().fatal(f"cannot start: {node.last_error}")
                return 1
            node.trigger_activate()
        executor = make_executor(str(node.get_parameter("executor").value))
        executor.add_node(node)
        spin_until_shutdown(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
