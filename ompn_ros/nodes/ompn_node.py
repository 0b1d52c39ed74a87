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
                      (:mod:`ompn_ros.data.cuts.gap`, the bag reader's ``split: gaps`` rule).
                      A driver that keeps publishing while the robot waits: ``idle_s`` > 0 ends an
                      episode once its speed stayed below ``idle_speed`` for ``idle_s`` (joint speed
                      in rad/s with ``obs_source: joint_state``; ``auto``: the training read's value,
                      else measured on the stream's first 10 s, :mod:`ompn_ros.nodes.ompn_node_idle`;
                      the reader's ``split: idle``, whose
                      end boundary is decided ``idle_s`` later; idle steps are held, then stepped or
                      trimmed, counted ``idle_trimmed``; a marker or ``~/reset`` ends the held ones as
                      the end of a bag does: the first is the final observation, the others trimmed).
    ``sketch``        Int32MultiArray: sketch of the coming episode (resets again if no step yet).
Service: ``~/reset`` (std_srvs/Trigger) starts a new episode and clears all per-episode state (and the
assembler's partner history; episode markers keep it); answered in every state, refused with the reason
while the node is not active.

Lifecycle: every transition is logged; a request the current state does not offer is refused with
``success: false`` and one line (:mod:`ompn_ros.nodes.lifecycle_guard`), and the shutdown transition ends
the process (exit 0).

Publications (per accepted observation, except one that a model with ``still_tolerance`` does not step:
:mod:`ompn_ros.data.cuts.still`, counted ``still_observations``; built by :mod:`ompn_ros.data.messages`, the
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
                      (the episode's last message), kind: one SUBTASK_END per subtask, never repeated,
                      or, closing an episode whose last subtask's end was out already, an EPISODE_END
                      (docs/design.md#episode-end).
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
starts, counted (``clock_jumps``) with a warning, unless only the stamps' clock moved: the robot's
header clock (JointState, spec input with ``stamp: header``, judged at the step message's arrival) or
the node's wall clock stamping at reception (judged against the steady clock; not under
``use_sim_time``) stepped, which neither starts nor cuts an episode (``clock_steps``; docs/specs.md,
"Clocks").  These stamp and episode rules (markers, pauses, idle,
resets) are :mod:`ompn_ros.stream.rule`, which the offline replay runs too: a recorded stream replayed
with its stamps (:func:`ompn_ros.stream.replay.replay_stream`) gives what the node published.

Executor: ``executor='events'`` (default) = ``rclpy.experimental.EventsExecutor``, the lower
observation -> boundary latency against ``'single'`` = ``SingleThreadedExecutor``
(docs/design.md#streaming-node).  Its ``spin()`` serves nothing in rclpy 7.1.6, so
:func:`ompn_ros.ros.run.run_node` drives it with ``spin_once``.  Parameters and when they apply:
:mod:`ompn_ros.nodes.ompn_node_params`.
"""

from __future__ import annotations

import gc
import sys
import threading
import time
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ompn_ros.data.cuts import GAP_TIMER_FRACTION, IdleSpeed
from ompn_ros.data.obs import ObservationSpecError
from ompn_ros.detect.errors import DetectorConfigError, DetectorSettingsError
from ompn_ros.detect.parameters import DetectorParameters
from ompn_ros.errors import OMPNError
from ompn_ros.model.errors import CheckpointError, ConfigError
from ompn_ros.nodes.clock_watch import ClockWatch, clock_ns, guard_clock_topic
from ompn_ros.nodes.duplicate_name import duplicate_line, same_name_count
from ompn_ros.nodes.lifecycle_guard import guard_change_state
from ompn_ros.nodes.ompn_node_checkpoint import check_model, default_sketch, resolve_checkpoint
from ompn_ros.nodes.ompn_node_idle import IdleProbe, chosen_idle_speed
from ompn_ros.nodes.ompn_node_inputs import NodeInputs
from ompn_ros.nodes.ompn_node_obs import AssembledInput, joint_input, load_spec, spec_line
from ompn_ros.nodes.ompn_node_outputs import NodePublishers
from ompn_ros.nodes.ompn_node_params import EXECUTORS, OBS_SOURCES, SPECS
from ompn_ros.ros.params import ParameterError, ParamTable
from ompn_ros.ros.run import NodeProcess, run_node
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.stream.rule import StreamLimits

NODE_NAME = "ompn_node"
__all__ = ["EXECUTORS", "NODE_NAME", "OBS_SOURCES", "NodeConfigError", "OMPNNode", "main"]


class NodeConfigError(OMPNError, ValueError):
    """A parameter or the checkpoint does not fit; the message is the transition's failure reason."""


class OMPNNode(LifecycleNode):
    """Lifecycle node: configure = load + validate the checkpoint, activate = subscribe and run.

    It owns its parts: :attr:`outputs` (``NodePublishers``: the publishers and the stream rule they
    publish for, :attr:`stream`, shared with the offline replay), :attr:`inputs` (``NodeInputs``: the
    subscriptions) and :attr:`detector` (``DetectorParameters``: the detector parameters' precedence)."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = ParamTable(SPECS)
        self.values = self.params.declare(self)  # ParameterError on an invalid start-up value
        # detector parameters given on the command line or in a params file win over the checkpoint's
        self.detector = DetectorParameters(getattr(self, "_parameter_overrides", {}))
        self.detector.config(self.values)  # cross-checks the detector parameters as a whole
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.outputs = NodePublishers(self, self.values, lambda: self.get_clock().now().nanoseconds)
        self.stream = self.outputs.stream
        self.inputs = NodeInputs(self, self.values, self.outputs, self._idle_found)
        self.events = self.stream.events  # the node's counters (counters())
        self.last_error = ""
        self.configure_error: Exception | None = None  # of the last failed configure
        self.quiet_configure = False
        self._timer: Any = None
        self._gap_timer: Any = None
        self.finished = threading.Event()  # set by the shutdown transition: main() then exits
        self._clock_watch = ClockWatch()
        self._duplicates = 0  # other nodes with this node's full name (seen on the graph)
        self._idle_speed: float | None = None  # idle_speed resolved (auto: at configure or from the stream)
        self._cache_limits()
        guard_clock_topic(self, self._on_clock)  # a negative /clock is dropped, not fatal
        guard_change_state(self, self.get_logger().warning)  # an invalid request is refused, not fatal
        self._service: Any = self.create_service(Trigger, "~/reset", self._on_reset)  # in every state

    @property
    def segmenter(self) -> StreamingSegmenter | None:
        """The configured segmenter (``None`` before configure and after cleanup)."""
        return self.stream.segmenter

    @property
    def assembled(self) -> AssembledInput | None:
        """The ``observation_spec`` input (``None``: a single topic, or not configured)."""
        return self.inputs.spec.assembled

    def _cache_limits(self) -> None:
        """The stream limits in ns and the default sketch, read once per change rather than once per step."""
        # without a known idle speed (auto, measured once active) the idle rule waits: idle_s 0 until then
        known = self._idle_speed is not None
        self.stream.limits = StreamLimits.of({**self.values, "idle_speed": self._idle_speed if known else 0.0,
                                              "idle_s": self.values["idle_s"] if known else 0.0})
        assembled = self.inputs.spec.assembled
        if assembled is not None and assembled.asm.step_header_stamped:  # the robot's clock stamps the steps
            self.stream.limits.header_topic = assembled.spec.step_topic
        self.stream.default_sketch = default_sketch(self.values)
        self._clock_watch.stall_ns = round(float(self.values["clock_stall"]) * 1e9)
        self._clock_watch.jump_forward_ns = round(float(self.values["clock_jump_forward"]) * 1e9)

    # --- parameters ----------------------------------------------------------------------------
    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        result = self.params.check_changes(params, active=self.inputs.active)
        if not result.successful:
            return result
        merged = dict(self.values)
        merged.update({p.name: p.value for p in params if p.name in self.params.specs})
        reason = self.detector.refusal(merged)
        return result if reason is None else SetParametersResult(successful=False, reason=reason)

    def _apply_parameters(self, params: list[Any]) -> None:
        """Post-set: remember the values; live detector changes apply from the next step."""
        names = {p.name for p in params if p.name in self.params.specs}
        self.values.update({p.name: p.value for p in params if p.name in self.params.specs})
        self._cache_limits()
        if self.detector.changed(names) and self.segmenter is not None:
            config = self.detector.config(self.values)
            when = self.segmenter.set_detector(config)  # checked by _on_set_parameters
            self.get_logger().info(f"detector now {config} ({when})")

    # --- lifecycle -----------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except Exception as exc:  # any failure is the transition's reason, never a crash
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.configure_error = exc
            if not self.quiet_configure:  # main() reports an auto-start failure itself, in one line
                self.get_logger().error(f"configure failed: {self.last_error}")
            self._unload()
            return TransitionCallbackReturn.FAILURE
        self.last_error = ""
        # Everything alive now (torch, numba, the model) leaves the cyclic collector, whose full passes
        # over it would pause the stream (docs/design.md#streaming-node).
        gc.collect()
        gc.freeze()
        return TransitionCallbackReturn.SUCCESS

    def _configure(self) -> None:
        import torch  # torch and the model load here, not at import: --help stays light

        from ompn_ros.model.load import stepper_from_checkpoint

        torch.set_num_threads(int(self.values["torch_threads"]))
        spec = load_spec(str(self.values["observation_spec"]), self.get_namespace())
        try:
            path = resolve_checkpoint(self.values)
        except ValueError as exc:
            raise NodeConfigError(str(exc)) from exc
        stored, line = self.detector.load(
            path, lambda taken: self.set_parameters([Parameter(n, value=v) for n, v in taken.items()]))
        self.get_logger().info(line)
        self._idle_speed, line = chosen_idle_speed(self.values, path, self.stream.limits.idle_elements)
        self._cache_limits()
        if line:
            self.get_logger().info(line)
        policy = stepper_from_checkpoint(path)
        try:
            check_model(self.values, policy.config)
            joints = joint_input(self.values)
        except ValueError as exc:
            raise NodeConfigError(str(exc)) from exc
        obs_dim, depth = int(policy.config.obs_dim), int(self.values["qos_depth"])
        self.inputs.configure(None if spec is None else AssembledInput(spec, obs_dim, depth), joints)
        self._cache_limits()  # the assembler's stamp source decides the header topic
        segmenter = StreamingSegmenter(policy, self.detector.config(self.values), stored.duration_model,
                                       stored.head)
        default = self.stream.default_sketch
        if segmenter.needs_sketch and default is not None:
            segmenter.reset(default)
            self.stream.episode_sketch = default
        self.stream.segmenter = segmenter
        self.outputs.create(policy.config, self.inputs.source())
        self.get_logger().info(configured_line(path, policy.config, segmenter.detector_config))
        if spec is not None:
            self.get_logger().info(spec_line(spec))

    def _unload(self) -> None:
        """Forget the model and the configured input (a failed configure, cleanup)."""
        self.stream.segmenter = None
        self.inputs.configure(None, self.inputs.joint_states.joints)
        self.detector.unload()

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.segmenter is None:
            self.last_error = "activate without a configured segmenter"
            return TransitionCallbackReturn.FAILURE
        measure = float(self.values["idle_s"]) > 0 and self._idle_speed is None  # idle_speed auto, no record
        self.inputs.subscribe(IdleProbe(self.stream.limits.idle_elements) if measure else None)
        # the steady clock: /diagnostics (and the stall check) go on while a simulator's /clock stands still
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        period = float(self.values["diagnostics_period"])
        self._timer = self.create_timer(period, self._health_tick, clock=steady)
        # a step of the wall clock stamping observations at reception is told on the steady clock;
        # under use_sim_time the sim's clock going back is a restart
        self.inputs.steady = None if self.get_parameter("use_sim_time").value else time.monotonic_ns
        self.stream.arm()
        gap_ns = self.stream.limits.gap_ns
        if gap_ns > 0:  # the node's clock: simulated time under use_sim_time
            self._gap_timer = self.create_timer(gap_ns * GAP_TIMER_FRACTION / 1e9, self._check_silence)
        self.get_logger().info("activated")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        self.get_logger().info("deactivated")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        gc.unfreeze()  # the model being dropped can be collected again
        self.outputs.destroy()
        self._unload()
        self.get_logger().info("cleaned up")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown_inputs()
        self.get_logger().info(f"shut down from '{state.label}'")
        self.finished.set()
        return TransitionCallbackReturn.SUCCESS

    def _teardown_inputs(self) -> None:
        self.inputs.unsubscribe()
        for timer in (self._timer, self._gap_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._timer = self._gap_timer = None
        self.stream.disarm()

    # --- episodes ------------------------------------------------------------------------------
    def _check_silence(self) -> None:
        """Timer of ``episode_gap``: end an open episode that had no step for ``episode_gap`` s."""
        if self.inputs.active:
            self.stream.check_silence()

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if not self.inputs.active:
            state = self._state_machine.current_state[1]
            response.success = False
            response.message = f"not reset: the node is '{state}'; ~/reset starts episodes only while active"
            return response
        self.inputs.release_all()  # held steps are stepped first: they came before the request
        response.success = self.stream.markers.reset()
        response.message = "memory reset" if response.success else "reset failed (no segmenter or no sketch)"
        return response

    def _idle_found(self, derived: IdleSpeed, rows: int) -> None:
        """``idle_speed: auto`` measured on the stream's first ``rows`` observations: the idle rule runs."""
        self._idle_speed = derived.speed
        self.get_logger().info(f"{derived.text}, from the stream's first {rows} observations")
        self._cache_limits()
        self.stream.arm()  # nothing was stepped while the probe held the observations

    # --- health --------------------------------------------------------------------------------
    def counters(self) -> dict[str, int]:
        """Health counters, also on /diagnostics (:meth:`NodePublishers.counters` names them)."""
        return self.outputs.counters(self.inputs.counters())

    def publish_diagnostics(self) -> None:
        """Publish the counters on /diagnostics (silently skipped once the context is shutting down)."""
        self.outputs.publish_diagnostics(self.counters(), self.inputs.dropped_total, self._duplicates)

    def _on_clock(self, msg: Any) -> bool:
        """Before rclpy's /clock handler: drop a negative time; a forward leap starts a new episode."""
        verdict = self._clock_watch.on_clock(clock_ns(msg), time.monotonic_ns())
        if verdict == "negative":
            self.events["clock_negative"] += 1
            self.outputs.warn_throttled(f"/clock message dropped: negative time {clock_ns(msg)} ns", False)
            return False
        if verdict == "forward":
            self.events["clock_jumps_forward"] += 1
            self.get_logger().warning(
                f"/clock jumped ahead to {clock_ns(msg)} ns (more than clock_jump_forward="
                f"{self.values['clock_jump_forward']} s): starting a new episode"
            )
            if self.segmenter is not None and self.inputs.active and self.segmenter.ready:
                self.stream.restart_episode()
        return True

    def _health_tick(self) -> None:
        """Steady-clock timer: a /clock stall and a second node of this name are reported once, then
        the counters go out on /diagnostics."""
        if self._clock_watch.stalled(time.monotonic_ns()) and self.get_parameter("use_sim_time").value:
            self.events["clock_stalls"] += 1
            self.get_logger().warning(stall_line(self.values["clock_stall"], self._clock_watch.last_ns))
        duplicates = same_name_count(self) - 1
        if duplicates > self._duplicates:
            self.get_logger().warning(duplicate_line(self.get_fully_qualified_name(), duplicates))
        self._duplicates = max(0, duplicates)
        self.publish_diagnostics()


def configured_line(path: object, config: Any, detector: object) -> str:
    """The log line of a configured node: its checkpoint, model and detector."""
    return (f"configured: checkpoint={path} obs_dim={config.obs_dim} n_slots={config.n_slots} "
            f"action={config.action_type} sketch_mode={config.sketch_mode} detector={detector}")


def stall_line(stall_s: object, last_ns: int | None) -> str:
    """The warning of a ``/clock`` that stood still for ``clock_stall`` s at ``last_ns``."""
    return (f"/clock has not advanced for clock_stall={stall_s} s (stuck at {last_ns} ns): is the "
            "simulator paused or hung? Steps keep one stamp")


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
