"""What the sim nodes (craft_sim, dial_sim) share: parameters, topic layout, modes, time and the main loop.

A sim node subclasses :class:`SimNode` and implements the domain hooks (``begin_episode``,
``observation``, ``current_subtask``, ``expert_action``, ``apply_action``, ``episode_success`` and
optionally ``publish_step_extras`` and ``make_streams``).  The base class owns the state machine and, with
the default streams (:class:`LayoutPublisher`), publishes strictly in the step contract of
:mod:`ompn_ros.layout`::

    start marker, sketch, (observation_t, [extras_t], subtask_t, action_t) * T, observation_T, end marker

Every message is built as CDR bytes by the codec (:mod:`ompn_ros.data.messages`)
and handed to rclpy as an already serialized message.

Modes:

* ``expert``: the domain's expert chooses every action; one step per timer tick (``rate`` Hz).  With
  ``demonstrator:=human`` the human-like demonstrator does (:mod:`sim_nodes.human`; ``human`` sets
  its parameters as ``NAME=VALUE`` strings): the node publishes that episode's recorded observations,
  each as often as its ``observation_copies`` say (0: dropped, 2: duplicated).
* ``policy``: after publishing ``observation_t`` the node waits for one message on ``cmd_action`` and
  executes it.  A missing action produces a throttled warning every ``policy_timeout`` seconds and the
  node holds; it never crashes on bad or missing input (bad actions are logged and ignored).  A
  discrete DONE action (``action == domain.action_dim``) ends the episode: the last observation then
  serves as the final one.  In this mode ``subtask_t`` is published together with ``action_t`` (after
  the command arrived), so a DONE leaves no dangling subtask message.

``rate`` = 0 means as fast as possible (expert: a batch of steps per 1 ms tick; policy: the step runs
in the ``cmd_action`` callback).  ``episodes`` = 0 means forever; otherwise the process ends (exit code 0,
:func:`serve_sim`) after the last episode.  Episode ``i`` uses ``derive_seed(seed, i)``.
``episode_pause`` holds the node that many (wall-clock) seconds between episodes.

**Time.**  A sim keeps its own *simulated time*: it advances by ``step_ns`` (40 ms, 25 Hz, unless the
domain says otherwise) per step and by ``max(1 s, episode_pause)`` before every episode (the first one
included, so no stamp is 0), and never goes back while the node runs.  With ``publish_clock:=true``
(the default, as a simulator does) the sim publishes it (``rosgraph_msgs/Clock``) before each
observation on ``clock_topic``: the relative ``clock`` by default, i.e. ``/clock`` for a sim without a
namespace and ``<ns>/clock`` for a namespaced one, so that two namespaced sims never interleave their
clocks on one topic.  A node that follows a namespaced sim's time runs with ``use_sim_time:=true`` and
the remapping ``/clock:=<ns>/clock`` (the launch files add it); ``clock_topic:=/clock`` makes a
namespaced sim the graph's global clock.  The sim's step timer runs on the steady clock, so it never
waits for its own clock.  Every stamp the sim writes (episode markers, ``JointState`` headers) comes
from ONE source: the simulated time when it publishes its clock, otherwise the node clock (wall time,
or another publisher's ``/clock`` under ``use_sim_time:=true``).

**QoS.**  The step-contract topics and ``cmd_action`` use :data:`SIM_QOS` (reliable, depth 100: the
1 kHz zero-loss path).  ``sensor_msgs/JointState`` is published like a robot driver does, with the
sensor-data profile (BEST_EFFORT, depth 5; ``joint_states_qos:=reliable`` for subscribers that only
accept RELIABLE publishers); ``/clock`` is reliable with depth 1, so both reliable and best-effort
clock subscribers receive it.

``wait_for_subscribers`` = N (> 0) holds the first episode until every topic in ``wait_topics``
(default ``['*']``: all topics of the sim, the recorder case; an ``ompn_node`` in policy mode only needs
``['observation']``) has N matched subscribers (a subscriber whose QoS does not match is not
counted) and, in policy mode, ``cmd_action`` has a matched publisher (an answer sent before that
match would be lost), then waits 0.5 s more.  Invalid parameters raise :class:`ParameterError` at
startup; the node's ``main()`` (:func:`ompn_ros.ros.run.run_node`) prints it in one line and exits
with code 2.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray

from ompn_ros import layout
from ompn_ros.data import messages
from ompn_ros.data.episode import Episode, observation_copies
from ompn_ros.layout import DomainLayout
from ompn_ros.ros.params import ParameterError, ParamSpec, ParamTable
from ompn_ros.ros.run import NodeProcess
from sim_nodes import SEED_MAX, derive_seed
from sim_nodes.human import DEMONSTRATORS, HumanLike, HumanLikeError, parse_human

try:
    from ompn_interfaces.msg import EpisodeMarker
except ImportError:  # an ompn_interfaces built before the message: the deprecated markers only
    EpisodeMarker = None

SIM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of the step-contract topics (and of ``cmd_action``): reliable, volatile, depth 100."""

SENSOR_QOS: QoSProfile = qos_profile_sensor_data
"""QoS of ``JointState`` (``joint_states_qos:=sensor_data``): best effort, volatile, depth 5."""

CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)  # fmt: skip
"""QoS of ``/clock``: reliable (serves reliable and best-effort subscribers), depth 1."""

CLOCK_TOPIC = "clock"  # the default of clock_topic: /clock, or <ns>/clock under a namespace
MODES = ("expert", "policy")
EPISODE_GAP_NS = layout.EPISODE_GAP_NS  # minimum simulated time between two episodes
_FAST_TICK_S = 0.001
_FAST_BATCH = 64  # steps per tick when rate == 0
_LINGER_S = 0.5  # keep spinning after the last episode so reliable messages get delivered
_SETTLE_S = 0.5
_FINAL_ANSWER_GRACE_S = 1.0


def _topic_name_rule(value: Any) -> str | None:
    """``ParamSpec`` check of ``clock_topic``: a valid ROS topic name (absolute or relative)."""
    from rclpy.validate_topic_name import validate_topic_name

    try:
        validate_topic_name(str(value))
    except Exception as exc:  # rclpy's InvalidTopicNameException: its reason
        return str(exc).splitlines()[0]
    return None


COMMON_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("mode", "expert", "'expert' or 'policy' (actions from cmd_action)", choices=MODES),
    ParamSpec(
        "rate", 10.0, "steps per second (0 = as fast as possible)", float_range=(0.0, 1e4), apply="live"
    ),
    ParamSpec("seed", 0, "base seed; episode i uses derive_seed(seed, i)", int_range=(0, SEED_MAX)),
    ParamSpec("episodes", 0, "number of episodes to run, then exit (0 = forever)", int_range=(0, 2**31 - 1)),
    ParamSpec(
        "policy_timeout", 5.0, "policy mode: seconds without cmd_action before a (throttled) warning",
        float_range=(0.01, 3600.0), apply="live",
    ),
    ParamSpec(
        "wait_for_subscribers", 0,
        "before the first episode, wait until this many subscribers are matched on every topic of"
        " 'wait_topics' (then 0.5 s more)",
        int_range=(0, 100),
    ),
    ParamSpec(
        "wait_topics", ["*"], "topics checked by wait_for_subscribers; '*' = every topic the sim publishes",
    ),
    ParamSpec(
        "publish_clock", True,
        "publish the simulated time on /clock and stamp every message with it (false: stamps from the"
        " node clock)",
    ),
    ParamSpec(
        "clock_topic", CLOCK_TOPIC,
        "where publish_clock publishes: 'clock' = /clock, or <ns>/clock under a namespace (namespaced sims"
        " never interleave); '/clock' = the global clock even under a namespace",
        check=_topic_name_rule,
    ),
    ParamSpec(
        "episode_pause", 0.0, "wall-clock seconds the sim holds between two episodes",
        float_range=(0.0, 3600.0), apply="live",
    ),
    ParamSpec(
        "demonstrator", "expert",
        "expert mode: 'expert' (scripted) or 'human' (human-like: pauses, tempo, overshoots, wrong moves"
        " undone, sensor noise, dropped/duplicated observation messages)", choices=DEMONSTRATORS,
    ),
    ParamSpec(
        "human", Parameter.Type.STRING_ARRAY,
        "demonstrator 'human': parameters as NAME=VALUE (ranges MIN:MAX), e.g. [pause_rate=0.05];"
        " unset = the domain's defaults (docs/craft.md, docs/dial.md)",
    ),
)  # fmt: skip


def human_parameters(domain: str, params: dict[str, Any]) -> HumanLike | None:
    """The human-like demonstrator's parameters of a sim node (``None``: the scripted expert);
    raises :class:`ParameterError` naming ``human`` or ``demonstrator``."""
    items = list(params["human"] or [])
    if params["demonstrator"] != "human":
        if items:
            raise ParameterError("human", "sets the human-like demonstrator: add demonstrator:=human")
        return None
    if params["mode"] != "expert":
        raise ParameterError("demonstrator", "'human' demonstrates in mode:=expert only")
    try:
        return parse_human(domain, items)
    except HumanLikeError as exc:
        raise ParameterError("human", str(exc)) from None


# --- message builders: CDR bytes from the codec (one place for the layout's message shapes) -----------
def encode_observation(obs: np.ndarray) -> bytes:
    """``Float32MultiArray`` with ``layout.dim=[('obs', D, D)]``."""
    return messages.encode_float32_array(obs, label="obs")


def encode_sketch(ids: np.ndarray) -> bytes:
    """``Int32MultiArray`` of the episode's subtask ids, dimension labelled ``sketch``."""
    return messages.encode_int32_array(np.asarray(ids).ravel(), label="sketch")


def encode_action(domain: DomainLayout, action: Any) -> bytes:
    """The executed action in the domain's message type (Int32 or Float32MultiArray labelled 'action')."""
    if domain.action_msg == layout.INT32:
        return messages.encode_int32(int(action))
    return messages.encode_float32_array(np.asarray(action, dtype=np.float32), label="action")


def encode_marker(stamp_ns: int, phase: str, values: dict[str, object]) -> bytes:
    """The episode start/end ``DiagnosticArray`` (status name 'episode', message 'start'|'end')."""
    text = {key: messages.marker_value(value) for key, value in values.items()}
    return messages.encode_diagnostic_status(stamp_ns, layout.EPISODE_STATUS_NAME, phase, text)


def action_msg_type(domain: DomainLayout) -> type:
    return Int32 if domain.action_msg == layout.INT32 else Float32MultiArray


def parse_action(domain: DomainLayout, msg: Any) -> int | np.ndarray:
    """Action from a ``cmd_action`` message; ``ValueError`` naming the problem if it does not fit."""
    if domain.action_type == "discrete":
        value = int(msg.data)
        if not 0 <= value <= domain.action_dim:  # action_dim itself = DONE
            raise ValueError(f"cmd_action {value} outside 0..{domain.action_dim} (the last one = done)")
        return value
    data = np.asarray(msg.data, dtype=np.float32)
    if data.shape != (domain.action_dim,) or not np.all(np.isfinite(data)):
        raise ValueError(f"cmd_action needs {domain.action_dim} finite floats, got shape {data.shape}")
    return data


@dataclass
class EpisodeStart:
    """What ``begin_episode`` reports: the task, the seed actually used and the sketch ids."""

    task: str
    seed: int
    sketch: np.ndarray


class Streams(Protocol):
    """What a sim publishes at each position of the step contract (the layout, or a robot's topics)."""

    def topic_names(self) -> list[str]:
        """Relative names of the topics these streams publish (``wait_topics`` choices)."""
        ...

    def episode_start(self, index: int, start: EpisodeStart, stamp_ns: int) -> None: ...

    def observation(self, obs: np.ndarray) -> None: ...

    def subtask(self, ordinal: int) -> None: ...

    def action(self, action: Any) -> None: ...

    def episode_end(self, index: int, start: EpisodeStart, steps: int, success: bool, stamp_ns: int) -> None:
        ...


class LayoutPublisher:
    """:class:`Streams` of the topic layout (:mod:`ompn_ros.layout`), one method per contract position."""

    def __init__(self, node: Node, domain: DomainLayout) -> None:
        self.domain = domain
        self.observation_pub = node.create_publisher(Float32MultiArray, layout.OBSERVATION, SIM_QOS)
        self.subtask_pub = node.create_publisher(Int32, layout.SUBTASK, SIM_QOS)
        self.action_pub = node.create_publisher(action_msg_type(domain), layout.ACTION, SIM_QOS)
        self.sketch_pub = node.create_publisher(Int32MultiArray, layout.SKETCH, SIM_QOS)
        # Episode markers, typed on 'episode_marker'; for one release also the deprecated string-keyed
        # DiagnosticArray on 'episode' (ompn_node, the reader and bag_recorder read either).
        self.marker_pub = None if EpisodeMarker is None else \
            node.create_publisher(EpisodeMarker, layout.EPISODE_MARKER, SIM_QOS)
        self.episode_pub = node.create_publisher(DiagnosticArray, layout.EPISODE, SIM_QOS)
        if self.marker_pub is None:
            node.get_logger().warning(
                "ompn_interfaces has no EpisodeMarker (built before it): publishing the deprecated "
                "DiagnosticArray markers on 'episode' only; rebuild it (ompn_interfaces/build_venv.py)")

    def topic_names(self) -> list[str]:
        return list(layout.topic_types(self.domain))

    def episode_start(self, index: int, start: EpisodeStart, stamp_ns: int) -> None:
        values = messages.start_marker_values(index, start.task, start.seed, start.sketch)
        self._marker(stamp_ns, layout.EPISODE_START, values)
        self.sketch_pub.publish(encode_sketch(start.sketch))

    def observation(self, obs: np.ndarray) -> None:
        self.observation_pub.publish(encode_observation(obs))

    def subtask(self, ordinal: int) -> None:
        self.subtask_pub.publish(messages.encode_int32(int(ordinal)))

    def action(self, action: Any) -> None:
        self.action_pub.publish(encode_action(self.domain, action))

    def episode_end(self, index: int, start: EpisodeStart, steps: int, success: bool, stamp_ns: int) -> None:
        values = messages.end_marker_values(index, start.task, start.seed, steps, success)
        self._marker(stamp_ns, layout.EPISODE_END, values)

    def _marker(self, stamp_ns: int, kind: str, values: dict[str, object]) -> None:
        """The typed marker first, then its deprecated twin (a reader of both keeps the first)."""
        if self.marker_pub is not None:
            self.marker_pub.publish(messages.encode_typed_marker(kind, stamp_ns, values))
        self.episode_pub.publish(encode_marker(stamp_ns, kind, values))


class SimNode(Node):
    """Base of a sim node: parameters, publishers, simulated time, expert/policy state machine.

    Subclass hooks below; ``step_ns`` (simulated nanoseconds per step) may be set by the subclass.
    """

    def __init__(self, node_name: str, domain: DomainLayout, domain_params: Sequence[ParamSpec] = ()) -> None:
        super().__init__(node_name)
        self.domain = domain
        self.param_table = ParamTable(sim_params(domain_params))
        self.params = self.param_table.declare(self)
        self.mode: str = self.params["mode"]
        self.rate: float = float(self.params["rate"])
        self.policy_timeout: float = float(self.params["policy_timeout"])
        self.episode_pause: float = max(float(self.params["episode_pause"]), self.min_episode_pause())
        self.publish_clock: bool = bool(self.params["publish_clock"])
        self.human = human_parameters(domain.name, self.params)
        self.demo: Episode | None = None  # the human-like episode being published (its recorded rows)
        self.step_ns: int = layout.STEP_NS
        self.sim_time_ns = 0  # simulated time, monotonic over the node's life
        self.streams = self.make_streams()
        self._clock_pub = (
            self.create_publisher(ClockMsg, str(self.params["clock_topic"]), CLOCK_QOS)
            if self.publish_clock else None
        )
        self.finished = False
        self.episode_index = 0
        self.step_index = 0
        self._start: EpisodeStart | None = None  # None between episodes
        self._pending_action: Any = None
        self._awaiting_since = 0.0
        # Policy mode: a policy also answers the final observation; wait (briefly) for that answer and
        # drop it, so that it is never executed as the answer to the next episode's first observation.
        self._drain_until = 0.0
        self._resume_at = 0.0  # end of the pause between episodes (monotonic seconds)
        self._ready_since: float | None = None
        self._wait_topic_names = self._wait_topics()
        self._cmd_sub = None if self.mode != "policy" else self.create_subscription(
            action_msg_type(domain), layout.CMD_ACTION, self._on_cmd_action, SIM_QOS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # The step timer runs on the steady clock: under use_sim_time a ROS-time timer would wait for
        # the /clock this node itself publishes only when it steps.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = self.create_timer(self._tick_period(), self._tick, clock=self._steady)

    # --- hooks -------------------------------------------------------------------------------------
    def make_streams(self) -> Streams:
        """The publishers of the step contract (called once, after the parameters are declared)."""
        return LayoutPublisher(self, self.domain)

    def begin_episode(self, index: int, seed: int) -> EpisodeStart:
        """Reset the simulation for episode ``index`` from ``seed``; return task, seed used, sketch."""
        raise NotImplementedError

    def observation(self) -> np.ndarray:
        """The current observation vector (length ``domain.obs_dim``)."""
        raise NotImplementedError

    def current_subtask(self) -> int:
        """Ground-truth subtask ordinal of the step about to be taken."""
        raise NotImplementedError

    def expert_action(self) -> Any:
        """The expert's action for the current state (expert mode)."""
        raise NotImplementedError

    def apply_action(self, action: Any) -> bool:
        """Execute ``action``; return True when the episode is over."""
        raise NotImplementedError

    def episode_success(self) -> bool:
        raise NotImplementedError

    def publish_step_extras(self, final: bool) -> None:
        """Called right after each observation (e.g. joint_states, render); ``final`` for observation_T."""

    # --- time ----------------------------------------------------------------------------------------
    def stamp_ns(self) -> int:
        """The stamp of anything published now: simulated time with ``publish_clock``, else the node clock."""
        return self.sim_time_ns if self.publish_clock else self.get_clock().now().nanoseconds

    def _advance(self, ns: int) -> None:
        """Advance the simulated time by ``ns`` and publish it on /clock."""
        self.sim_time_ns += int(ns)
        if self._clock_pub is not None:
            self._clock_pub.publish(messages.encode_clock(self.sim_time_ns))

    # --- parameters ----------------------------------------------------------------------------------
    def _tick_period(self) -> float:
        return 1.0 / self.rate if self.rate > 0 else _FAST_TICK_S

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        result = self.param_table.check_changes(params)
        if not result.successful:
            return result
        for p in params:
            if p.name == "rate":
                self.rate = float(p.value)
                self._timer.cancel()
                self.destroy_timer(self._timer)
                self._timer = self.create_timer(self._tick_period(), self._tick, clock=self._steady)
            elif p.name == "policy_timeout":
                self.policy_timeout = float(p.value)
            elif p.name == "episode_pause":
                self.episode_pause = max(float(p.value), self.min_episode_pause())
        return SetParametersResult(successful=True)

    def min_episode_pause(self) -> float:
        """Lower bound of ``episode_pause`` (a domain profile may require a pause)."""
        return 0.0

    # --- state machine -------------------------------------------------------------------------------
    def _wait_topics(self) -> list[str]:
        known = self.streams.topic_names()
        names = list(self.params["wait_topics"])
        if "*" in names:
            return known
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ParameterError("wait_topics", f"unknown topics {unknown}; this sim publishes {known}")
        return names

    def _ready(self) -> bool:
        wanted = int(self.params["wait_for_subscribers"])
        if wanted == 0 or (self._ready_since is not None and time.monotonic() >= self._ready_since):
            return True
        answered = self._cmd_sub is None or self._cmd_sub.get_publisher_count() >= 1
        if self._ready_since is None and answered and all(
            max(p.get_subscription_count() for p in group) >= wanted for group in self._waited_groups()
        ):
            # The subscriber's other topics are matched a moment later: settle before publishing.
            self._ready_since = time.monotonic() + _SETTLE_S
        return False

    def _waited_groups(self) -> list[list[Any]]:
        """The publishers waited for, one group per topic a consumer reads: the typed episode marker and
        its deprecated twin are one (a consumer subscribes to either form)."""
        resolved = {self.resolve_topic_name(t) for t in self._wait_topic_names}
        markers = {self.resolve_topic_name(t) for t in (layout.EPISODE_MARKER, layout.EPISODE)}
        waited = [p for p in self.publishers if p.topic_name in resolved]
        twins = [p for p in waited if p.topic_name in markers]
        return [[p] for p in waited if p.topic_name not in markers] + ([twins] if twins else [])

    def observation_copies(self) -> int:
        """How many times the current observation is published (the human-like demonstrator drops and
        duplicates some); 1 otherwise."""
        return 1 if self.demo is None else int(observation_copies(self.demo)[self.step_index])

    def _publish_observation(self, final: bool = False) -> None:
        obs = self.observation() if self.demo is None else self.demo.observations[self.step_index]
        for _ in range(self.observation_copies()):
            self.streams.observation(obs)
        self.publish_step_extras(final)
        self._pending_action = None  # a command sent before this observation is stale
        self._awaiting_since = time.monotonic()

    def _start_episode(self) -> None:
        seed = derive_seed(int(self.params["seed"]), self.episode_index)
        self._advance(max(EPISODE_GAP_NS, round(self.episode_pause * 1e9)))
        self._start = self.begin_episode(self.episode_index, seed)
        self.step_index = 0
        self.streams.episode_start(self.episode_index, self._start, self.stamp_ns())
        self._publish_observation()

    def _end_episode(self) -> None:
        assert self._start is not None
        success = self.episode_success()
        self.streams.episode_end(self.episode_index, self._start, self.step_index, success, self.stamp_ns())
        self._start = None
        self._resume_at = time.monotonic() + self.episode_pause
        self.episode_index += 1
        total = int(self.params["episodes"])
        if total and self.episode_index >= total:
            self.finished = True
            self._timer.cancel()

    def _take_step(self, action: Any) -> None:
        self.streams.subtask(self.current_subtask())
        self.streams.action(action)
        over = self.apply_action(action)
        self.step_index += 1
        self._advance(self.step_ns)
        self._publish_observation(final=over)
        if over:
            if self.mode == "policy":
                self._drain_until = time.monotonic() + min(self.policy_timeout, _FINAL_ANSWER_GRACE_S)
            self._end_episode()

    def _tick(self) -> None:
        if self.finished or not self._ready():
            return
        for _ in range(_FAST_BATCH if self.rate == 0 else 1):
            if self._start is None:
                if time.monotonic() < max(self._drain_until, self._resume_at):
                    return  # pausing, or waiting for the policy's answer to the final observation
                self._start_episode()
                if self.mode == "policy":
                    return
            if self.mode == "expert":
                self._take_step(self.expert_action())
            else:
                self._policy_step()
            if self.finished or self.mode == "policy":
                return

    def _policy_step(self) -> None:
        if self._start is None:
            return
        if self._pending_action is None:
            waited = time.monotonic() - self._awaiting_since
            if waited > self.policy_timeout:
                self.get_logger().warning(
                    f"no cmd_action for {waited:.1f} s (episode {self.episode_index},"
                    f" step {self.step_index}); holding",
                    throttle_duration_sec=self.policy_timeout,
                )
            return
        action, self._pending_action = self._pending_action, None
        if self.domain.action_type == "discrete" and int(action) == self.domain.action_dim:
            self._end_episode()  # the policy's DONE: the last observation is the final one
            return
        self._take_step(action)

    def _on_cmd_action(self, msg: Any) -> None:
        if self._start is None or self.finished:
            self._drain_until = 0.0  # the answer to the final observation: dropped, next episode may start
            return
        try:
            self._pending_action = parse_action(self.domain, msg)
        except (ValueError, TypeError) as exc:
            self.get_logger().warning(f"ignoring cmd_action: {exc}", throttle_duration_sec=1.0)
            return
        if self.rate == 0:
            self._policy_step()


def sim_params(domain_params: Sequence[ParamSpec]) -> list[ParamSpec]:
    """The parameter table of a sim: the common rows, then the domain's own; a domain row overrides the
    common row of its name (dial_sim's real-time ``rate``)."""
    return list({s.name: s for s in (*COMMON_PARAMS, *domain_params)}.values())


def serve_sim(node: SimNode, process: NodeProcess) -> int:
    """The serve function of a sim (:func:`ompn_ros.ros.run.run_node`): until its last episode ended
    (exit 0) or a signal, then a moment more so that reliable messages still in flight get delivered."""
    code = process.serve(lambda: 0 if node.finished else None)
    process.linger(_LINGER_S)
    return code
