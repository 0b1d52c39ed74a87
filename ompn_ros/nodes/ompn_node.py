"""ompn_node: lifecycle ROS 2 node that runs the OMPN online on every observation.

A thin wrapper around :class:`ompn_ros.segmenter.StreamingSegmenter` (Lu et al., ICLR 2021, Sec. 2:
the ordered memory is stepped once per observation; boundaries follow Algorithm 1, made causal).

Subscriptions (while active; names from :mod:`ompn_ros.layout`, relative to the namespace):
    ``observation``   Float32MultiArray (``obs_source='array'``), or ``joint_states`` JointState
                      (``obs_source='joint_state'``: the ``joint_fields`` arrays concatenated, joints in
                      ``joint_names`` order; ``joint_merge`` merges several publishers by joint name, the
                      reader's ``merge_s``; an empty field is rejected in one line).  QoS from
                      ``obs_qos`` (default ``best_effort``: receives from RELIABLE and BEST_EFFORT
                      publishers); an incompatible publisher is reported in one line naming ``obs_qos``.
    spec topics       with ``observation_spec`` set instead: every topic of the spec (its type, QoS from
                      ``obs_qos``); each message of the step topic is one step, assembled by
                      :class:`ompn_ros.data.obs.ObservationAssembler` (the bag reader's rule: latest
                      partner at or before the step within ``tolerance_s``, else a dropped step, counted
                      by reason as ``obs.dropped.<reason>``).  A step waits up to ``wait_s`` for the
                      header-stamped partners stamped at or after it (``obs.late`` counts the steps
                      decided without them); episode markers and ``~/reset`` first step the held steps.
                      The publishers' types are checked about once a second; a wrong type is one line
                      and a counter (:mod:`ompn_ros.nodes.ompn_node_obs`).
    ``episode``       DiagnosticArray episode marker: 'start' resets the memory (sketch from the
                      marker, else the latest ``sketch`` message, else the ``sketch`` parameter);
                      'end' closes the last segment at step ``steps - 1``.
                      Without markers, ``episode_gap`` > 0 splits episodes at pauses: a step stamped
                      more than ``episode_gap`` s after the previous one, or that long without a step
                      (the node's clock), ends the episode like an end marker and starts the next
                      (:mod:`ompn_ros.nodes.episode_gap`, the bag reader's ``split: gaps`` rule).
                      A driver that keeps publishing while the robot waits: ``idle_s`` > 0 ends an
                      episode once the observation changed by less than ``idle_speed`` per second for
                      ``idle_s`` (the reader's ``split: idle``; still steps are held, then stepped or
                      trimmed, counted ``idle_trimmed``; a marker or ``~/reset`` ends the held ones as
                      the end of a bag does: the first is the final observation, the others trimmed).
    ``sketch``        Int32MultiArray: sketch of the coming episode (resets again if no step yet).
Service: ``~/reset`` (std_srvs/Trigger) starts a new episode and clears all per-episode state (and the
assembler's partner history; episode markers keep it); answered in every state, refused with the reason
while the node is not active.

Lifecycle: every transition is logged; a request the current state does not offer is refused with
``success: false`` and one line (:mod:`ompn_ros.nodes.lifecycle_guard`), and the shutdown transition ends
the process (exit 0).

Publications (per accepted observation; built by :mod:`ompn_ros.data.messages`, the
``ompn_interfaces`` types included):
    ``cmd_action``    Int32 (discrete: argmax env action, or ``action_dim`` = 'done' when
                      π_end > ``done_threshold``) or Float32MultiArray (continuous: Gaussian mean).
    ``~/state``       ompn_interfaces/msg/SubtaskState: header (the observation's stamp and frame_id),
                      episode, step, ``pi`` (π_1..π_n, lowest slot first), ``expected_position``
                      (Σ i·π_i, paper π_avg), ``pi_end``.
    ``~/pi``          Float32MultiArray, the same numbers packed: π_1..π_n, Σ i·π_i, π_end (one
                      dimension of n + 2 values, label ``layout.PI_LABEL``).
    ``~/boundary``    ompn_interfaces/msg/SubtaskBoundary: header (stamp = the boundary step's input
                      stamp, frame_id = the observation's), node, episode, step, subtask, subtask_id (from
                      the sketch, -1 unknown), score, memory_level, decided_step and decided_stamp, final
                      (every episode's last boundary; when the detector published it before the episode
                      ended, it comes again with final set: :func:`ompn_ros.detect.online.with_final`).
                      RELIABLE; a late subscriber gets the last event only
                      (``boundary_replay='last'``, TRANSIENT_LOCAL depth 1) or nothing old ('none').
    ``/diagnostics``  periodic DiagnosticArray, one status named '<fully qualified node name>: segmenter'
                      with the counters (:meth:`OMPNNode.counters`).

Bad input never stops the node: a message that cannot be used is skipped without stepping the model,
counted by reason (``rejected_<reason>``) and reported with a throttled warning; an invalid sketch
rejects the episode's start (logged once) until the next valid one.  (A 0-byte message is dropped by
Fast DDS before it reaches any subscriber; delivered otherwise, it is counted as ``malformed``.)

Stamps and time: spec input uses the assembler's stamp rule, with the node's clock at reception as the
receive time (kept strictly increasing on the step topic); JointState input uses ``header.stamp``; array
input uses the DDS source timestamp (``executor='single'``, wall time) or, with the EventsExecutor (it
cannot deliver message info in rclpy 7.1.6) or ``use_sim_time``, the node's clock at reception.
Outputs carry the input's stamps, so under ``use_sim_time`` everything is in sim time.  A stamp more
than ``max_stamp_lead`` s ahead of the node's clock is rejected (``future_stamp``); one more than
``clock_jump_back`` s behind the last step is a clock restart (sim restart, looped bag): a new episode
starts, counted (``clock_jumps``) with a warning.

Executor: ``executor='events'`` (default) = ``rclpy.experimental.EventsExecutor``, measured to cut the
observation -> boundary latency by ~0.4-0.5 ms against ``'single'`` = ``SingleThreadedExecutor``
(BENCHMARKS.md).  Its ``spin()`` serves nothing in rclpy 7.1.6, so :func:`ompn_ros.ros.run.run_node`
drives it with ``spin_once``.  Parameters and when they apply: :mod:`ompn_ros.nodes.ompn_node_params`.
"""

from __future__ import annotations

import array
import gc
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray
from std_srvs.srv import Trigger

from ompn_interfaces.msg import SubtaskBoundary, SubtaskState
from ompn_ros import layout
from ompn_ros.checkpoints import MissingCheckpointError, shipped_checkpoint
from ompn_ros.data.messages import (
    StampRangeError,
    encode_diagnostic_status,
    encode_float32_array,
    encode_int32,
    encode_subtask_boundary,
    encode_subtask_state,
    join_stamp,
    parse_float32_array,
    parse_sketch_value,
)
from ompn_ros.data.messages import SubtaskBoundary as BoundaryFields
from ompn_ros.data.obs import Decided, Drop, ObservationSpecError
from ompn_ros.data.repeats import Repeats
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.errors import DetectorConfigError, DetectorSettingsError
from ompn_ros.detect.online import DURATION_MODE, BoundaryEvent, DetectorConfig, with_final
from ompn_ros.detect.settings import NODE_PARAMETERS, node_parameters, resolve_detector
from ompn_ros.errors import OMPNError
from ompn_ros.model.errors import CheckpointError, ConfigError
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.nodes.clock_watch import ClockWatch, clock_ns, guard_clock_topic
from ompn_ros.nodes.duplicate_name import duplicate_line, same_name_count
from ompn_ros.nodes.episode_gap import GAP_TIMER_FRACTION, IdleGate, SilenceWatch
from ompn_ros.nodes.lifecycle_guard import guard_change_state
from ompn_ros.nodes.ompn_node_obs import (
    MESSAGE_CLASSES,
    AssembledInput,
    JointInput,
    drop_line,
    joint_input,
    load_spec,
)
from ompn_ros.nodes.ompn_node_params import (
    EXECUTORS,
    OBS_SOURCES,
    SPECS,
    boundary_qos,
    input_qos,
    policy_kind_name,
)
from ompn_ros.ros.params import ParameterError, ParamTable
from ompn_ros.ros.run import NodeProcess, run_node
from ompn_ros.segmenter import (
    BadSketch,
    BadStamp,
    FutureStamp,
    InvalidInput,
    MalformedMessage,
    SketchError,
    StreamingSegmenter,
    classify_stamp,
)
from ompn_ros.validate import WrongObservationLength, validate_sketch

NODE_NAME = "ompn_node"
MARKER_QUEUE = 5_000  # depth of the marker (and sketch) topics, KEEP_ALL: a full queue holds publishers back
LEVEL_OK, LEVEL_WARN = 0, 1
LIVE_DETECTOR_KEYS = frozenset(
    {"detector_high", "detector_hysteresis", "detector_min_segment_length", "detector_mode",
     "detector_force_first_step_low", "detector_lag"}
)  # fmt: skip
__all__ = ["EXECUTORS", "NODE_NAME", "OBS_SOURCES", "NodeConfigError", "OMPNNode", "main"]


class NodeConfigError(OMPNError, ValueError):
    """A parameter or the checkpoint does not fit; the message is the transition's failure reason."""


def default_checkpoint(domain: str) -> Path | None:
    """The checkpoint shipped as package data for ``domain`` (``ompn_ros/checkpoints/<domain>``)."""
    try:
        return shipped_checkpoint(domain)
    except MissingCheckpointError:
        return None


def load_policy(path: str) -> Any:
    """The streaming stepper of a checkpoint directory, OMPN or LSTM (safetensors + JSON, never pickle)."""
    return stepper_from_checkpoint(path)


def detector_config(values: dict[str, Any]) -> DetectorConfig:
    """The detector of the ``detector_*`` parameter values (``low = high - hysteresis``).

    Raises :class:`DetectorConfigError` when ``detector_hysteresis`` exceeds ``detector_high`` (the run
    would end below a score of 0, so it would never end)."""
    high, hysteresis = float(values["detector_high"]), float(values["detector_hysteresis"])
    if hysteresis > high + 1e-9:
        raise DetectorConfigError(
            f"detector_hysteresis={hysteresis} exceeds detector_high={high}: a run would end only below a "
            "score of 0; set detector_hysteresis <= detector_high"
        )
    return DetectorConfig(
        high=high,
        low=max(0.0, high - hysteresis),
        min_segment_length=int(values["detector_min_segment_length"]),
        mode=str(values["detector_mode"]),
        force_first_step_low=bool(values["detector_force_first_step_low"]),
        lag=int(values["detector_lag"]),
    )


class OMPNNode(LifecycleNode):
    """Lifecycle node: configure = load + validate the checkpoint, activate = subscribe and run."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = ParamTable(SPECS)
        self.values = self.params.declare(self)  # ParameterError on an invalid start-up value
        detector_config(self.values)  # cross-checks the detector parameters as a whole
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        # detector parameters given on the command line, in a params file or set later: these win over
        # the checkpoint's own detector.json (explicit > checkpoint > defaults)
        overrides = getattr(self, "_parameter_overrides", {})
        self._explicit: set[str] = {name for name in NODE_PARAMETERS if name in overrides}
        self._from_checkpoint = False

        self.segmenter: StreamingSegmenter | None = None
        self.assembled: AssembledInput | None = None  # observation_spec input (None: single topic)
        self.last_error = ""
        self.configure_error: Exception | None = None  # of the last failed configure
        self.quiet_configure = False
        self.events: Counter[str] = Counter()  # node-level counters (counters())
        self.qos_warnings: list[str] = []
        self.last_stamp_ns = 0
        self._last_receive_ns = 0
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._timer: Any = None
        self._graph_timer: Any = None
        self._hold_timer: Any = None
        self._gap_timer: Any = None
        self._silence: SilenceWatch | None = None
        self._idle: IdleGate | None = None  # idle_s: the reader's split: idle rule
        self._repeats = Repeats()  # messages a driver sent twice: one step (the reader's rule)
        self._joints: JointInput | None = None  # obs_source 'joint_state'
        self._latest_sketch: np.ndarray | None = None
        self._episode_sketch: np.ndarray | None = None
        self._last_warn = -float("inf")
        self._fq_name = self.get_fully_qualified_name()  # the node field of ~/boundary
        self._frame_id = ""  # the observation's header.frame_id (JointState input)
        self._sizes_reported: set[str] = set()  # observation size mismatches logged (once each)
        self._last_boundary: tuple[BoundaryEvent, int] | None = None  # (event, decided stamp) of the episode
        self._n_slots = 0
        self._active = False
        self.finished = threading.Event()  # set by the shutdown transition: main() then exits
        self._jump_back_ns = self._max_lead_ns = self._gap_ns = 0
        self._clock_watch = ClockWatch()
        self._duplicates = 0  # other nodes with this node's full name (seen on the graph)
        self._cache_stamp_limits()
        guard_clock_topic(self, self._on_clock)  # a negative /clock is dropped, not fatal
        guard_change_state(self, self.get_logger().warning)  # an invalid request is refused, not fatal
        self._service: Any = self.create_service(Trigger, "~/reset", self._on_reset)  # in every state

    def _cache_stamp_limits(self) -> None:
        """The stamp limits in ns, read once per change rather than once per step."""
        self._jump_back_ns = int(float(self.values["clock_jump_back"]) * 1e9)
        self._max_lead_ns = int(float(self.values["max_stamp_lead"]) * 1e9)
        self._gap_ns = round(float(self.values["episode_gap"]) * 1e9)
        self._clock_watch.stall_ns = round(float(self.values["clock_stall"]) * 1e9)
        self._clock_watch.jump_forward_ns = round(float(self.values["clock_jump_forward"]) * 1e9)

    # --- parameters ----------------------------------------------------------------------------
    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        result = self.params.check_changes(params, active=self._active)
        if not result.successful:
            return result
        merged = dict(self.values)
        merged.update({p.name: p.value for p in params if p.name in self.params.specs})
        try:
            config = detector_config(merged)
        except DetectorConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        seg = self.segmenter
        no_model = seg is not None and seg.duration_model is None and not self._from_checkpoint
        if config.mode == DURATION_MODE and no_model:
            return SetParametersResult(successful=False, reason=(
                f"detector_mode '{DURATION_MODE}' needs a duration model, and this checkpoint's "
                "detector.json has none (ompn_train writes one)"))
        return result

    def _apply_parameters(self, params: list[Any]) -> None:
        """Post-set: remember the values; live detector changes apply from the next step."""
        names = {p.name for p in params if p.name in self.params.specs}
        if not self._from_checkpoint:
            self._explicit |= names & set(NODE_PARAMETERS)
        self.values.update({p.name: p.value for p in params if p.name in self.params.specs})
        self._cache_stamp_limits()
        if names & LIVE_DETECTOR_KEYS and self.segmenter is not None:
            config = detector_config(self.values)
            when = self.segmenter.set_detector(config)  # checked by _on_set_parameters
            self.get_logger().info(f"detector now {config} ({when})")

    def _default_sketch(self) -> np.ndarray | None:
        values = [int(v) for v in self.values["sketch"]]
        # [-1] = no default sketch: 0 is a valid id and ROS cannot declare an empty integer array
        return np.asarray(values, dtype=np.int64) if values != [-1] else None

    def _resolve_checkpoint(self) -> str:
        path, domain = str(self.values["checkpoint"]), str(self.values["domain"])
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
        domain = str(self.values["domain"])
        expected_dim = int(self.values["obs_dim"])
        expected_action = str(self.values["action_type"])
        if domain:
            dom = layout.DOMAINS[domain]
            if self.values["obs_source"] == "array" and not str(self.values["observation_spec"]).strip():
                expected_dim = expected_dim or dom.obs_dim
            expected_action = expected_action or dom.action_type
            if config.action_dim != dom.action_dim:
                raise NodeConfigError(
                    f"checkpoint action_dim={config.action_dim} does not fit domain "
                    f"'{domain}' (action_dim={dom.action_dim})"
                )
        if expected_dim and config.obs_dim != expected_dim:
            raise NodeConfigError(
                f"checkpoint obs_dim={config.obs_dim} does not match the expected "
                f"observation size {expected_dim}"
            )
        if expected_action and config.action_type != expected_action:
            raise NodeConfigError(
                f"checkpoint action_type='{config.action_type}' does not match the "
                f"expected '{expected_action}'"
            )
        sketch_mode = str(self.values["sketch_mode"])
        if sketch_mode and config.sketch_mode != sketch_mode:
            raise NodeConfigError(
                f"checkpoint sketch_mode='{config.sketch_mode}' does not match the expected '{sketch_mode}'"
            )

    def _apply_checkpoint_detector(self, path: str) -> DurationModel | None:
        """Fill the detector parameters nobody set explicitly from the checkpoint's ``detector.json``
        (``ompn_ros.detect.settings``) and log which settings run and where they came from; its duration
        model (mode 'hsmm'), if any."""
        settings, line = resolve_detector(path)
        stored = node_parameters(settings)
        take = [Parameter(n, value=stored[n]) for n in NODE_PARAMETERS if n not in self._explicit]
        self._from_checkpoint = True
        try:
            self.set_parameters(take)  # the ROS parameters show what runs
        finally:
            self._from_checkpoint = False
        explicit = sorted(self._explicit)
        self.get_logger().info(f"{line}; overridden by parameters: {explicit}" if explicit else line)
        return settings.duration_model

    # --- lifecycle -----------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except Exception as exc:  # any failure is the transition's reason, never a crash
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.configure_error = exc
            if not self.quiet_configure:  # main() reports an auto-start failure itself, in one line
                self.get_logger().error(f"configure failed: {self.last_error}")
            self.segmenter = None
            self.assembled = None
            return TransitionCallbackReturn.FAILURE
        self.last_error = ""
        # Everything alive now (torch, numba, the model: ~280 000 objects for Craft) leaves the cyclic
        # collector, whose full passes over it took ~157 ms in the middle of the stream (BENCHMARKS.md).
        gc.collect()
        gc.freeze()
        return TransitionCallbackReturn.SUCCESS

    def _configure(self) -> None:
        import torch

        torch.set_num_threads(int(self.values["torch_threads"]))
        spec = load_spec(str(self.values["observation_spec"]), self.get_namespace())
        path = self._resolve_checkpoint()
        duration_model = self._apply_checkpoint_detector(path)
        policy = load_policy(path)
        self._validate_model(policy.config)
        depth = int(self.values["qos_depth"])
        self.assembled = None if spec is None else AssembledInput(spec, int(policy.config.obs_dim), depth)
        try:
            self._joints = joint_input(self.values)
        except ValueError as exc:
            raise NodeConfigError(str(exc)) from exc
        segmenter = StreamingSegmenter(policy, detector_config(self.values), duration_model)
        default = self._default_sketch()
        if segmenter.needs_sketch and default is not None:
            segmenter.reset(default)
            self._episode_sketch = default
        self.segmenter = segmenter
        self._n_slots = int(policy.config.n_slots)
        per_step = QoSProfile(
            depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
        )
        action_type = Int32 if policy.config.action_type == "discrete" else Float32MultiArray
        events = PublisherEventCallbacks(
            incompatible_qos=lambda info: self._qos_mismatch("~/boundary", "boundary_replay", info)
        )
        self._pubs = {
            "action": self.create_lifecycle_publisher(action_type, layout.CMD_ACTION, per_step),
            "pi": self.create_lifecycle_publisher(Float32MultiArray, layout.PI, per_step),
            "state": self.create_lifecycle_publisher(SubtaskState, layout.STATE, per_step),
            "boundary": self.create_lifecycle_publisher(
                SubtaskBoundary,
                layout.BOUNDARY,
                boundary_qos(str(self.values["boundary_replay"])),
                event_callbacks=events,
            ),
            "diagnostics": self.create_lifecycle_publisher(DiagnosticArray, layout.DIAGNOSTICS, 10),
        }
        self.get_logger().info(
            f"configured: checkpoint={path} obs_dim={policy.config.obs_dim} n_slots={self._n_slots} "
            f"action={policy.config.action_type} sketch_mode={policy.config.sketch_mode} "
            f"detector={segmenter.detector_config}"
        )
        if spec is not None:
            self.get_logger().info(
                f"observation_spec: step topic {spec.step_topic}, topics {list(spec.topics)}, tolerance "
                f"{spec.tolerance_s} s, stamp {spec.stamp}, size {spec.declared_dim() or 'from the data'}"
            )

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.segmenter is None:
            self.last_error = "activate without a configured segmenter"
            return TransitionCallbackReturn.FAILURE
        inputs = input_qos(str(self.values["obs_qos"]), int(self.values["qos_depth"]))
        # KEEP_ALL: a full queue refuses new markers, and the reliable publisher resends them once the
        # node has read some, rather than the queue overwriting unread ones; what the middleware still
        # loses (a best-effort or shallow publisher) is counted (markers_lost)
        markers = QoSProfile(
            depth=MARKER_QUEUE, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL
        )
        # Markers first: when a marker and an observation are both ready, the executor serves the
        # subscriptions in creation order, so the 'start' reset precedes the episode's first step.
        self._subscribe(DiagnosticArray, layout.EPISODE, self._on_episode, markers, None)
        self._subscribe(Int32MultiArray, layout.SKETCH, self._on_sketch, markers, None)
        if self.assembled is not None:
            self._subscribe_spec(self.assembled, inputs)
        elif self.values["obs_source"] == "joint_state":
            self._subscribe(JointState, layout.JOINT_STATES, self._on_joint_state, inputs, "obs_qos")
        else:  # raw CDR: the float32 data is read in place, no message object is built
            callback = self._on_array_info if self.uses_message_info else self._on_array
            self._subscribe(Float32MultiArray, layout.OBSERVATION, callback, inputs, "obs_qos", raw=True)
        # the steady clock: /diagnostics (and the stall check) go on while a simulator's /clock stands still
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        period = float(self.values["diagnostics_period"])
        self._timer = self.create_timer(period, self._health_tick, clock=steady)
        if self._gap_ns > 0:  # the node's clock: simulated time under use_sim_time
            self._silence = SilenceWatch(self._gap_ns)
            self._gap_timer = self.create_timer(self._gap_ns * GAP_TIMER_FRACTION / 1e9, self._check_silence)
        if float(self.values["idle_s"]) > 0:
            self._idle = IdleGate(round(float(self.values["idle_s"]) * 1e9), float(self.values["idle_speed"]))
        self._active = True
        self.get_logger().info("activated")
        return super().on_activate(state)

    def _subscribe_spec(self, assembled: AssembledInput, qos: QoSProfile) -> None:
        """One raw subscription per spec topic, the publishers' types checked ~1/s.  Partners first: when
        a partner and a step message are both ready, a wait-set executor serves them in creation order,
        and the partner message, published first, is then fed first (as it arrived)."""
        spec = assembled.spec
        for topic in (*spec.partner_topics, spec.step_topic):
            callback = self._on_spec_step if topic == spec.step_topic else self._partner_callback(topic)
            msg_class = MESSAGE_CLASSES[spec.type_of(topic)]
            self._subscribe(msg_class, topic, callback, qos, "obs_qos", raw=True)
        self._graph_timer = self.create_timer(1.0, self._check_topic_types)
        self._check_topic_types()
        if assembled.asm.waited_topics:  # held steps are released on every message, and by this timer
            period = max(0.005, spec.wait_s / 2)
            self._hold_timer = self.create_timer(period, lambda: self._release_held(None))

    def _subscribe(
        self, msg_type: Any, topic: str, callback: Any, qos: QoSProfile, param: str | None, raw: bool = False
    ) -> None:
        lost = ("messages_lost", "markers_lost") if topic == layout.EPISODE else ("messages_lost",)
        events = SubscriptionEventCallbacks(
            incompatible_qos=lambda info: self._qos_mismatch(topic, param, info),
            message_lost=lambda info: self.events.update(dict.fromkeys(lost, info.total_count_change)),
        )
        self._subs.append(
            self.create_subscription(msg_type, topic, callback, qos, raw=raw, event_callbacks=events)
        )

    def _qos_mismatch(self, topic: str, param: str | None, info: Any) -> None:
        """One line per incompatible QoS pairing, naming the parameter to change."""
        policy = policy_kind_name(info.last_policy_kind)
        fix = (
            f"set parameter '{param}' (now '{self.values[param]}') to match the peer"
            if param
            else "the peer must use RELIABLE, VOLATILE-compatible QoS"
        )
        text = f"QoS of '{topic}' incompatible with a peer ({policy}, {info.total_count} so far): {fix}"
        self.events["qos_incompatible"] += 1
        self.qos_warnings.append(text)
        self.get_logger().error(text)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        self.get_logger().info("deactivated")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        gc.unfreeze()  # the model being dropped can be collected again
        for pub in self._pubs.values():
            self.destroy_lifecycle_publisher(pub)
        self._pubs = {}
        self.segmenter = None
        self.assembled = None
        self.get_logger().info("cleaned up")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        self.get_logger().info(f"shut down from '{state.label}'")
        self.finished.set()
        return TransitionCallbackReturn.SUCCESS

    def _teardown_inputs(self) -> None:
        self._active = False
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        for timer in (self._graph_timer, self._hold_timer, self._gap_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._graph_timer = self._hold_timer = self._gap_timer = None
        self._silence = self._idle = None
        if self.assembled is not None:
            self.assembled.asm.reset()  # held steps are decided (counted) but not stepped: inactive

    @property
    def uses_message_info(self) -> bool:
        """Array input takes its stamp from the DDS source timestamp (needs message info, wall time)."""
        return (
            self.values["obs_source"] == "array"
            and self.values["executor"] != "events"
            and not self.get_parameter("use_sim_time").value
        )

    # --- input callbacks (each one survives any message) ---------------------------------------
    def _on_array_info(self, raw: bytes, info: dict[str, Any]) -> None:
        self._on_raw_array(raw, int(info["source_timestamp"]))

    def _on_array(self, raw: bytes) -> None:
        # Without message info, stamp with the clock at reception, kept strictly increasing (a clock
        # that stands still, e.g. sim time between /clock ticks, must not turn into out-of-order
        # rejections); a clock that went back further than clock_jump_back is taken as it is.
        now = self.get_clock().now().nanoseconds
        last = self._last_receive_ns
        stamp = now if (now > last or last - now > self._jump_back_ns) else last + 1
        self._last_receive_ns = stamp
        self._on_raw_array(raw, stamp, now)

    def _on_raw_array(self, raw: bytes, stamp_ns: int, now_ns: int | None = None) -> None:
        if self._repeats.seen(layout.OBSERVATION, layout.FLOAT32_ARRAY, stamp_ns, raw):
            return  # the same message sent twice: one step
        try:
            data = parse_float32_array(raw)
        except Exception as exc:  # rosbags raises several types on bad CDR: counted, never fatal
            self._reject(MalformedMessage(f"undecodable Float32MultiArray ({len(raw)} bytes): {exc}"))
            return
        self.process_observation(data, stamp_ns, now_ns)

    def _on_spec_step(self, raw: bytes) -> None:
        """A step-topic message: held by the assembler (receive time = the node's clock, strictly
        increasing) until its partners caught up or ``wait_s`` passed, then stepped like any
        observation; a dropped step is counted by reason and warned (throttled)."""
        assembled = self.assembled
        if assembled is None or self.segmenter is None or not self._active:
            return
        now = self.get_clock().now().nanoseconds
        last = self._last_receive_ns
        receive = now if (now > last or last - now > self._jump_back_ns) else last + 1
        self._last_receive_ns = receive
        if self._repeats.seen(assembled.spec.step_topic, assembled.spec.type_of(assembled.spec.step_topic),
                              receive, raw):
            return
        try:
            assembled.asm.hold(receive, raw)
        except Exception as exc:  # the assembler counts what it knows; anything else is malformed input
            self._reject(MalformedMessage(f"step message not assembled: {type(exc).__name__}: {exc}"))
            return
        self._release_held(now)

    def _release_held(self, now_ns: int | None, flush: bool = False) -> None:
        """Step the held steps the assembler can decide now (all of them with ``flush``), in order."""
        assembled = self.assembled
        if assembled is None or not assembled.asm.held:
            return
        now = self.get_clock().now().nanoseconds if now_ns is None else now_ns
        try:
            decided = assembled.asm.release(now, flush)
        except Exception as exc:  # never fatal: counted as malformed input, warned
            self._reject(MalformedMessage(f"held steps not assembled: {type(exc).__name__}: {exc}"))
            return
        self._step_decided(assembled, decided, now)

    def _step_decided(self, assembled: AssembledInput, decided: list[Decided], now: int) -> None:
        for d in decided:
            if isinstance(d.result, Drop):
                self._warn_throttled(drop_line(d.result, assembled.dropped_total), with_total=False)
                continue
            problem = assembled.first_size_problem(d.result)
            if problem is not None:
                self.events["obs_size_mismatch"] += 1
                self.get_logger().error(problem)
            self.process_observation(d.result, d.stamp_ns, now)

    def _partner_callback(self, topic: str) -> Any:
        def on_partner(raw: bytes) -> None:
            assembled = self.assembled
            if assembled is None or not self._active:
                return
            now = self.get_clock().now().nanoseconds
            if self._repeats.seen(topic, assembled.spec.type_of(topic), now, raw):
                return
            try:
                rejected = assembled.asm.offer(topic, now, raw)
            except Exception as exc:  # never fatal: counted as a node event, warned
                self.events["obs_partner_errors"] += 1
                self._warn_throttled(f"message on '{topic}' not used: {type(exc).__name__}: {exc}")
                return
            if rejected is not None:
                self._warn_throttled(f"message rejected: {rejected}", with_total=False)
            self._release_held(now)

        return on_partner

    def _check_topic_types(self) -> None:
        """Compare the spec topics' advertised types with the spec (timer, ~1 s): one line per change."""
        if self.assembled is None:
            return
        try:
            graph = {t: [p.topic_type for p in self.get_publishers_info_by_topic(t)]
                     for t in self.assembled.spec.topics}
        except Exception as exc:  # the graph may be unavailable while the context shuts down
            if "context" not in str(exc):
                self._warn_throttled(f"ROS graph not readable: {exc}")
            return
        for line in self.assembled.check_graph(graph):
            if "expects" in line:
                self.get_logger().error(line)
            else:
                self.get_logger().info(line)

    def _on_joint_state(self, msg: JointState) -> None:
        try:
            stamp = join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec)
        except StampRangeError as exc:
            self._reject(BadStamp(str(exc)))
            return
        fields = {f: np.asarray(getattr(msg, f)) for f in layout.JOINT_FIELDS}
        payload = "\0".join(msg.name).encode() + b"".join(v.tobytes() + b"|" for v in fields.values())
        if self._repeats.seen_sample(layout.JOINT_STATES, stamp, payload):
            return  # the same sample sent twice (same header stamp and data): one step
        joints = self._joints or JointInput(self.values["joint_fields"], None, None)
        got = joints.observation(stamp, msg.name, fields)
        if got is None:  # joint_merge: another publisher's message, or a step lacking a joint (counted)
            return
        if isinstance(got, str):
            self._reject(MalformedMessage(got))
            return
        self._frame_id = msg.header.frame_id
        with np.errstate(over="ignore"):  # beyond float32 -> inf, which the segmenter rejects
            self.process_observation(got.astype(np.float32), stamp)

    def _reject(self, error: InvalidInput) -> None:
        if self.segmenter is not None and self._active:
            self.segmenter.count_rejection(error)
            self._warn_throttled(f"skipped input ({error.reason}): {error}")

    def process_observation(self, data: Any, stamp_ns: int | None, now_ns: int | None = None) -> None:
        """Step the segmenter on one observation and publish its outputs (or count a rejection).

        ``now_ns``: the node's clock at reception when the caller read it already."""
        seg = self.segmenter
        if seg is None or not self._active:
            return
        if stamp_ns is not None and not self._stamp_usable(seg, stamp_ns, now_ns):
            return
        if self._idle is not None and stamp_ns is not None:
            self._idle_steps(self._idle, np.array(data, dtype=np.float32), stamp_ns)
            return
        self._step(seg, data, stamp_ns)

    def _idle_steps(self, gate: IdleGate, obs: np.ndarray, stamp_ns: int) -> None:
        """``idle_s``: step what the idle rule decided (held still observations included, in order)."""
        self._idle_decided(gate.push(obs, stamp_ns))

    def _input_ends(self) -> None:
        """Before an episode marker or ``~/reset``: with ``idle_s`` the held still observations end the
        open episode as at the end of a bag (the first is its final observation, the others trimmed);
        the next message is never a repeat of one before."""
        self._repeats.forget()
        if self._idle is not None:
            self._idle_decided(self._idle.flush())

    def _idle_decided(self, decided: list[tuple[str, np.ndarray | None, int]]) -> None:
        """Step and close what the idle rule decided, in order (``IdleGate.push`` / ``flush``)."""
        for kind, x, stamp in decided:
            seg = self.segmenter
            if seg is None:
                return
            if kind == "start":
                self._start_episode(self._episode_sketch, count_bad=False)
            if x is not None:
                self._step(seg, x, stamp)
            if kind == "end" and seg.step_index >= 0 and not seg.detector.closed:
                self._close_episode(seg.step_index)  # the final observation (row T) is the last stepped

    def _step(self, seg: StreamingSegmenter, data: Any, stamp_ns: int | None) -> None:
        try:
            obs = (
                np.frombuffer(data, dtype=np.float32)
                if isinstance(data, array.array) and data.typecode == "f"
                else data
            )
            out = seg.step(obs, stamp_ns)
        except InvalidInput as exc:
            if isinstance(exc, WrongObservationLength):
                self._report_size_mismatch(exc)
            else:
                self._warn_throttled(f"skipped observation ({exc.reason}): {exc}")
            return
        self.last_stamp_ns = 0 if stamp_ns is None else int(stamp_ns)
        if out.step_index == 0:
            self.events["episodes"] += 1
        # The boundary event goes out first: it is the latency-critical product of this node
        # (logged after the per-step outputs, which must not wait for the console).
        if out.boundary is not None:
            self.publish_boundary(out.boundary, log=False)
        so = out.step_output
        config = seg.policy.config
        if config.action_type == "discrete":
            done = so.done_prob > self.values["done_threshold"]
            self._pubs["action"].publish(encode_int32(config.action_dim if done else so.action))
        else:
            self._pubs["action"].publish(encode_float32_array(so.action, "action"))
        n = self._n_slots
        pi_values = np.empty(n + 2, np.float32)
        pi_values[:n] = so.pi
        pi_values[n] = so.expected_position
        pi_values[n + 1] = so.pi_end
        self._pubs["pi"].publish(encode_float32_array(pi_values, layout.PI_LABEL))
        self._pubs["state"].publish(encode_subtask_state(
            self.last_stamp_ns, self._frame_id, self.events["episodes"], out.step_index, so.pi,
            so.expected_position, so.pi_end))
        if out.boundary is not None:
            self.log_boundary(out.boundary)

    def _report_size_mismatch(self, exc: WrongObservationLength) -> None:
        """One error line per observed size that does not fit the checkpoint (each such message is
        still skipped and counted as ``rejected_wrong_length``), naming where the size comes from."""
        if str(exc) in self._sizes_reported:
            return
        self._sizes_reported.add(str(exc))
        if self.assembled is not None:
            source = f"observation_spec (step topic {self.assembled.spec.step_topic})"
        elif self.values["obs_source"] == "joint_state":
            fields = list(self.values["joint_fields"])
            source = f"'{layout.JOINT_STATES}' fields {fields} (obs_source=joint_state)"
        else:
            source = f"'{layout.OBSERVATION}'"
        self.get_logger().error(
            f"{exc} from {source}: every such message is skipped (counted as rejected_wrong_length); "
            "publish what the model was trained on, or use a checkpoint trained on this robot")

    def _stamp_usable(self, seg: StreamingSegmenter, stamp_ns: int, now_ns: int | None) -> bool:
        """Reject a far-future stamp; a clock restart starts a new episode (counted, warned)."""
        if now_ns is None:
            now_ns = self.get_clock().now().nanoseconds if self._max_lead_ns > 0 else 0
        verdict = classify_stamp(
            stamp_ns, seg.last_stamp, now_ns, jump_back_ns=self._jump_back_ns, max_lead_ns=self._max_lead_ns
        )
        if verdict == "future":
            self._reject(
                FutureStamp(
                    f"stamp {stamp_ns} ns is more than max_stamp_lead="
                    f"{self.values['max_stamp_lead']} s ahead of the node's clock"
                )
            )
            return False
        if verdict == "jump_back":
            self.events["clock_jumps"] += 1
            self.get_logger().warning(
                f"input clock jumped back from {seg.last_stamp} to {stamp_ns} ns (more than "
                f"clock_jump_back={self.values['clock_jump_back']} s): starting a new episode"
            )
            if seg.detector.steps_seen > 0 and not seg.detector.closed:
                self._close_episode(None)
            started = self._start_episode(self._episode_sketch, count_bad=False)
            self.events["episode_starts"] += int(started)
            return started
        # episode_gap: gap_ends_episode() inlined, so with the split off a step pays one test
        if self._gap_ns and seg.last_stamp is not None and stamp_ns - seg.last_stamp > self._gap_ns:
            return self._end_at_pause()
        return True

    # --- outputs -------------------------------------------------------------------------------
    def publish_boundary(self, event: BoundaryEvent, log: bool = True, decided_ns: int | None = None) -> None:
        """Publish ``event`` on ``~/boundary`` (the codec's bytes, the node name and frame id encoded
        once) and, with ``log``, log it."""
        stamp = event.stamp_ns or self.get_clock().now().nanoseconds
        decided = self.last_stamp_ns if decided_ns is None else decided_ns
        self._pubs["boundary"].publish(encode_subtask_boundary(BoundaryFields.from_event(
            event, node=self._fq_name, episode=self.events["episodes"], frame_id=self._frame_id,
            sketch=self._episode_sketch, decided_stamp_ns=decided, stamp_ns=stamp)))
        self._last_boundary = (event, decided)
        self.events["boundaries"] += 1
        if log:
            self.log_boundary(event)

    def log_boundary(self, event: BoundaryEvent) -> None:
        self.get_logger().info(
            f"subtask boundary: step={event.step} subtask={event.subtask} score={event.score:.3f} "
            f"level={event.level} detected_at={event.detected_at}{' (episode end)' if event.final else ''}"
        )

    def _warn_throttled(self, text: str, with_total: bool = True) -> None:
        now = time.monotonic()
        if now - self._last_warn >= float(self.values["warn_throttle"]):
            self._last_warn = now
            total = self.segmenter.rejected_total if self.segmenter else 0
            self.get_logger().warning(f"{text} [{total} rejected so far]" if with_total else text)

    # --- episodes ------------------------------------------------------------------------------
    def _start_episode(self, sketch: np.ndarray | None, count_bad: bool = True) -> bool:
        """Reset the memory and every per-episode state (stamps included) for a new episode."""
        seg = self.segmenter
        if seg is None:
            return False
        if sketch is None or sketch.size == 0:
            sketch = self._latest_sketch if self._latest_sketch is not None else self._default_sketch()
        try:
            seg.reset(sketch)
        except SketchError as exc:
            seg.stop()
            if count_bad:
                seg.count_rejection(BadSketch(str(exc)))
            self.get_logger().warning(f"episode start rejected: {exc}; waiting for the next valid start")
            return False
        seg.forget_stamps()
        self._last_boundary = None
        self._last_receive_ns = 0
        self.last_stamp_ns = 0
        self._episode_sketch = sketch
        return True

    def _close_episode(self, steps: int | None) -> None:
        """Close the last segment at ``steps - 1`` (the marker's count; the last step seen if unknown)."""
        seg = self.segmenter
        assert seg is not None
        last = seg.step_index
        if steps is not None and steps < last:  # fewer steps than observed: the marker is wrong
            self.events["bad_end_markers"] += 1
            self.get_logger().warning(
                f"end marker says steps={steps} after {last + 1} observations: closing at the last step seen"
            )
            steps = None
        closing = seg.end_episode(steps - 1 if steps is not None and steps > 0 else None)
        self.events["episodes_ended"] += 1
        for event in closing:
            self.publish_boundary(event)
        if self._last_boundary is not None:  # the boundary published at the end comes again as final
            last, decided = self._last_boundary
            for event in with_final([last])[1:]:
                self.publish_boundary(event, decided_ns=decided)

    def _end_at_pause(self) -> bool:
        """``episode_gap``: close the open episode as an end marker would and start the next one."""
        seg = self.segmenter
        assert seg is not None
        if seg.detector.steps_seen > 0 and not seg.detector.closed:
            self._close_episode(None)
        self.events["episode_gaps"] += 1
        if self._silence is not None:
            self._silence.rearm()
        if self._idle is not None:
            self._idle.reset()
        return self._start_episode(self._episode_sketch, count_bad=False)

    def _check_silence(self) -> None:
        """Timer of ``episode_gap``: end an open episode that had no step for ``episode_gap`` s."""
        seg, watch = self.segmenter, self._silence
        if seg is None or watch is None or not self._active:
            return
        open_episode = seg.ready and seg.step_index >= 0 and not seg.detector.closed
        if watch.quiet(self.get_clock().now().nanoseconds, seg.step_index, open_episode):
            self._end_at_pause()

    def _on_episode(self, msg: DiagnosticArray) -> None:
        self._release_held(None, flush=True)  # held steps belong to the episode before the marker
        for status in msg.status:
            if status.name != layout.EPISODE_STATUS_NAME or self.segmenter is None or not self._active:
                continue
            self.events["markers"] += 1
            self._input_ends()
            values = {kv.key: kv.value for kv in status.values}
            if status.message == layout.EPISODE_START:
                self._on_start_marker(values.get(layout.KEY_SKETCH, ""))
            elif status.message == layout.EPISODE_END and self.segmenter.ready:
                steps = _int_or_none(values.get(layout.KEY_STEPS, ""))
                if not self.segmenter.detector.closed:
                    self._close_episode(steps)
                self._start_episode(self._episode_sketch, count_bad=False)  # steps before the next start

    def _on_start_marker(self, text: str) -> None:
        seg = self.segmenter
        assert seg is not None
        vocab = getattr(seg.policy.config, "sketch_vocab", None) if seg.needs_sketch else None
        try:
            sketch = parse_sketch_value(text, None if vocab is None else int(vocab))
        except SketchError as exc:
            seg.count_rejection(BadSketch(str(exc)))
            if seg.needs_sketch:
                seg.stop()
                self.get_logger().warning(
                    f"episode start rejected: marker {exc}; waiting for the next valid start"
                )
                return
            sketch = None  # this model ignores sketches: the episode starts anyway
        self._latest_sketch = sketch if sketch is not None and sketch.size else None
        if self._start_episode(sketch):
            self.events["episode_starts"] += 1

    def _on_sketch(self, msg: Int32MultiArray) -> None:
        seg = self.segmenter
        if seg is None or not self._active or len(msg.data) == 0:
            return
        sketch = np.asarray(msg.data, dtype=np.int64)
        if seg.needs_sketch:
            vocab = getattr(seg.policy.config, "sketch_vocab", None)
            try:
                sketch = validate_sketch(sketch, None if vocab is None else int(vocab))
            except SketchError as exc:
                seg.count_rejection(BadSketch(str(exc)))
                self._warn_throttled(f"sketch message rejected: {exc}")
                return
        self._latest_sketch = sketch
        if not seg.ready or seg.step_index < 0:  # no step yet: the episode starts with this sketch
            self._start_episode(sketch)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if not self._active:
            state = self._state_machine.current_state[1]
            response.success = False
            response.message = f"not reset: the node is '{state}'; ~/reset starts episodes only while active"
            return response
        if self.assembled is not None:  # held steps are stepped first: they came before the request
            self._step_decided(self.assembled, self.assembled.asm.reset(), self.get_clock().now().nanoseconds)
        self._input_ends()
        response.success = self._start_episode(self._episode_sketch)
        self.events["episode_starts"] += int(response.success)
        response.message = "memory reset" if response.success else "reset failed (no segmenter or no sketch)"
        return response

    # --- health --------------------------------------------------------------------------------
    def _on_clock(self, msg: Any) -> bool:
        """Before rclpy's /clock handler: drop a negative time; a forward leap starts a new episode."""
        verdict = self._clock_watch.on_clock(clock_ns(msg), time.monotonic_ns())
        if verdict == "negative":
            self.events["clock_negative"] += 1
            self._warn_throttled(f"/clock message dropped: negative time {clock_ns(msg)} ns", False)
            return False
        if verdict == "forward":
            self.events["clock_jumps_forward"] += 1
            self.get_logger().warning(
                f"/clock jumped ahead to {clock_ns(msg)} ns (more than clock_jump_forward="
                f"{self.values['clock_jump_forward']} s): starting a new episode"
            )
            seg = self.segmenter
            if seg is not None and self._active and seg.ready:
                if seg.detector.steps_seen > 0 and not seg.detector.closed:
                    self._close_episode(None)
                started = self._start_episode(self._episode_sketch, count_bad=False)
                self.events["episode_starts"] += int(started)
        return True

    def _health_tick(self) -> None:
        """Steady-clock timer: a /clock stall and a second node of this name are reported once, then
        the counters go out on /diagnostics."""
        if self._clock_watch.stalled(time.monotonic_ns()) and self.get_parameter("use_sim_time").value:
            self.events["clock_stalls"] += 1
            self.get_logger().warning(
                f"/clock has not advanced for clock_stall={self.values['clock_stall']} s (stuck at "
                f"{self._clock_watch.last_ns} ns): is the simulator paused or hung? Steps keep one stamp"
            )
        duplicates = same_name_count(self) - 1
        if duplicates > self._duplicates:
            self.get_logger().warning(duplicate_line(self.get_fully_qualified_name(), duplicates))
        self._duplicates = max(0, duplicates)
        self.publish_diagnostics()

    def counters(self) -> dict[str, int]:
        """Health counters (also on /diagnostics): accepted steps, rejected inputs (total and by
        reason), episodes (that had a step), episode_starts (accepted start markers, ~/reset calls and
        clock restarts), episodes_ended (end markers, pauses and clock restarts that closed an episode),
        episode_gaps (pauses of ``episode_gap`` seen), markers (episode markers handled: every marker
        received is counted here or, when the middleware lost it, in markers_lost), messages_lost (all
        topics, reported by the middleware),
        boundaries published, clock_jumps (input stamps back by more than ``clock_jump_back``),
        clock_jumps_forward (``/clock`` ahead by more than ``clock_jump_forward``), clock_stalls (``/clock``
        stood still for ``clock_stall``), clock_negative (negative ``/clock`` times dropped),
        bad_end_markers, qos_incompatible (and duplicate_names on /diagnostics); with ``observation_spec``
        also the assembler's ``obs.*`` counters (steps, kept, dropped by reason, rejected partner
        messages by topic and reason), ``obs_type_reports`` (wrong advertised types seen) and
        ``obs_size_mismatch``; with ``idle_s`` ``idle_trimmed`` (still observations in no episode), with
        ``joint_merge`` ``joint_missing`` (steps dropped for a joint without a recent value);
        ``repeated_messages``: messages a driver sent twice, stepped once (:mod:`ompn_ros.data.repeats`)."""
        seg = self.segmenter
        out = {"accepted": 0, "rejected": 0}
        if seg is not None:
            out.update(accepted=seg.accepted, rejected=seg.rejected_total)
        for key in (
            "episodes",
            "episode_starts",
            "episodes_ended",
            "episode_gaps",
            "markers",
            "markers_lost",
            "messages_lost",
            "boundaries",
            "clock_jumps",
            "clock_jumps_forward",
            "clock_stalls",
            "clock_negative",
            "bad_end_markers",
            "qos_incompatible",
        ):
            out[key] = int(self.events[key])
        if seg is not None:
            out.update({f"rejected_{k}": int(v) for k, v in seg.rejected.items()})
        out["repeated_messages"] = self._repeats.total
        if self._idle is not None:
            out["idle_trimmed"] = self._idle.trimmed
        if self._joints is not None and self._joints.merger is not None:
            out["joint_missing"] = self._joints.missing
        if self.assembled is not None:
            out.update(self.assembled.counters())
            out["obs_type_reports"] = self.assembled.type_reports
            out["obs_size_mismatch"] = int(self.events["obs_size_mismatch"])
        return out

    def publish_diagnostics(self) -> None:
        """Publish the counters on /diagnostics (silently skipped once the context is shutting down)."""
        pub = self._pubs.get("diagnostics")
        if pub is None or not self.context.ok():
            return
        counters = self.counters()
        dropped = self.assembled.dropped_total if self.assembled is not None else 0
        rejected = counters["rejected"] > 0 or dropped > 0
        counters["duplicate_names"] = self._duplicates
        message = "rejected input" if rejected else "ok"
        if self._duplicates:
            message = f"duplicate node name: {self._duplicates + 1} nodes publish this status"
        raw = encode_diagnostic_status(
            self.get_clock().now().nanoseconds, f"{self.get_fully_qualified_name()}: segmenter",
            message, counters, LEVEL_WARN if rejected or self._duplicates else LEVEL_OK,
        )  # fmt: skip
        try:
            pub.publish(raw)
        except Exception as exc:  # SIGINT tears the context down while the timer is due: not an error
            # (checked again here: the context may have gone between the check above and the call,
            # and then logging, which publishes to /rosout, would raise in its turn)
            if self.context.ok() and "context" not in str(exc):
                self._warn_throttled(f"/diagnostics not published: {exc}")


def _int_or_none(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None


KNOWN_CONFIGURE_ERRORS = (NodeConfigError, CheckpointError, ConfigError, DetectorConfigError,
                          DetectorSettingsError, ObservationSpecError, FileNotFoundError)
"""Configure failures caused by the parameters or the checkpoint (not by a bug in this package)."""


def _cannot_start(node: OMPNNode) -> Exception:
    """Why the auto-start configure failed: a known cause as :class:`NodeConfigError` ('cannot start:
    ...': one line, exit code 2); anything else is a bug, logged as FATAL and raised again with its
    traceback (exit code 1)."""
    exc = node.configure_error
    if isinstance(exc, KNOWN_CONFIGURE_ERRORS):
        return NodeConfigError(f"cannot start: {exc}")
    node.get_logger().fatal(f"cannot start: {node.last_error}")
    return exc if exc is not None else RuntimeError(f"cannot start: {node.last_error}")


def _started_node() -> OMPNNode:
    """The node, configured and activated when ``auto_start`` is set; a detector parameter that does
    not fit the others is a parameter error (``detector_*``)."""
    try:
        node = OMPNNode()
    except DetectorConfigError as exc:
        raise ParameterError("detector_*", str(exc)) from None
    if node.values["auto_start"]:
        node.quiet_configure = True
        node.trigger_configure()
        node.quiet_configure = False
        if node.segmenter is None:
            error = _cannot_start(node)
            node.destroy_node()
            raise error
        node.trigger_activate()
    return node


def _serve(node: OMPNNode, process: NodeProcess) -> int:
    """Serve until a signal or the shutdown transition (both exit 0)."""
    return process.serve(lambda: 0 if node.finished.is_set() else None)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ompn_node``: configure + activate (``auto_start``), then spin.

    Exit codes: 0 after SIGINT/SIGTERM or the shutdown transition, 2 when the auto-start configure
    fails for a known cause (a missing checkpoint, one that does not fit the domain or parameters: one
    line), 1 for any other configure failure (a bug: its traceback), 2 on an invalid start-up parameter
    (one line naming it and the allowed values) or unparsable ROS arguments (rcl's reason, e.g. an
    unquoted YAML mapping given to ``-p observation_spec:=``: pass a file path or quote the mapping as
    a YAML string)."""
    return run_node(NODE_NAME, _started_node, args, serve=_serve, errors=(NodeConfigError,),
                    executor=lambda node: str(node.values["executor"]), params=SPECS,
                    about="Online subtask segmentation: steps the OMPN on every observation and "
                    "publishes the action, ~/pi and ~/boundary events.")


if __name__ == "__main__":
    sys.exit(main())
