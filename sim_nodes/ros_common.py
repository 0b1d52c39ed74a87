"""What the sim nodes (craft_sim, dial_sim) share: parameters, the topic layout, modes and the main loop.

A sim node subclasses :class:`SimNode` and implements the domain hooks (``begin_episode``,
``observation``, ``current_subtask``, ``expert_action``, ``apply_action``, ``episode_success`` and
optionally ``publish_step_extras``).  The base class owns the state machine and publishes strictly in
the step contract of :mod:`ompn_ros.layout`::

    start marker, sketch, (observation_t, [extras_t], subtask_t, action_t) * T, observation_T, end marker

Modes:

* ``expert``: the domain's expert chooses every action; one step per timer tick (``rate`` Hz).
* ``policy``: after publishing ``observation_t`` the node waits for one message on ``cmd_action`` and
  executes it.  A missing action produces a throttled warning every ``policy_timeout`` seconds and the
  node holds; it never crashes on bad or missing input (bad actions are logged and ignored).  A
  discrete DONE action (``action == domain.action_dim``) ends the episode: the last observation then
  serves as the final one.  In this mode ``subtask_t`` is published together with ``action_t`` (after
  the command arrived), so a DONE leaves no dangling subtask message.

``rate`` = 0 means as fast as possible (expert: a batch of steps per 1 ms tick; policy: the step runs
in the ``cmd_action`` callback).  ``episodes`` = 0 means forever; otherwise the node returns from
:func:`run_sim_node` after the last episode.  Episode ``i`` uses ``derive_seed(seed, i)``.

``wait_for_subscribers`` = N (> 0) holds the first episode until every topic in ``wait_topics``
(default ``['*']``: all topics of the sim, the recorder case; an ``ompn_node`` in policy mode only needs
``['observation']``) has N matched subscribers, then waits 0.5 s more.  All topics use :data:`SIM_QOS`.
Invalid parameters raise :class:`ParameterError` at startup; :func:`run_sim_node` prints it and
returns exit code 2.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray, MultiArrayDimension

from ompn_ros import layout
from ompn_ros.layout import DomainLayout
from ompn_ros.nodes.params import ParameterError, ParamSpec, ParamTable
from sim_nodes import SEED_MAX, derive_seed

SIM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of every sim topic (and of ``cmd_action``): reliable, volatile, depth 100."""

MODES = ("expert", "policy")
_FAST_TICK_S = 0.001
_FAST_BATCH = 64  # steps per tick when rate == 0
_LINGER_S = 0.5  # keep spinning after the last episode so reliable messages get delivered
_SETTLE_S = 0.5
_FINAL_ANSWER_GRACE_S = 1.0


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
)  # fmt: skip


# --- message builders (one place for the layout's message shapes) -------------------------------------
def observation_msg(obs: np.ndarray) -> Float32MultiArray:
    """``Float32MultiArray`` with ``layout.dim=[('obs', D, D)]``."""
    data = np.asarray(obs, dtype=np.float32).ravel()
    msg = Float32MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="obs", size=data.size, stride=data.size)]
    msg.data = data.tolist()
    return msg


def sketch_msg(ids: np.ndarray) -> Int32MultiArray:
    data = [int(i) for i in np.asarray(ids).ravel()]
    msg = Int32MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="subtask", size=len(data), stride=len(data))]
    msg.data = data
    return msg


def action_msg(domain: DomainLayout, action: Any) -> Int32 | Float32MultiArray:
    """The executed action in the domain's message type (Int32 or Float32MultiArray labelled 'action')."""
    if domain.action_msg == layout.INT32:
        return Int32(data=int(action))
    data = np.asarray(action, dtype=np.float32).ravel()
    msg = Float32MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="action", size=data.size, stride=data.size)]
    msg.data = data.tolist()
    return msg


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


def episode_marker(stamp: Any, phase: str, values: dict[str, Any]) -> DiagnosticArray:
    """The episode start/end ``DiagnosticArray`` (status name 'episode', message 'start'|'end')."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=layout.EPISODE_STATUS_NAME, message=phase)
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    msg.status = [status]
    return msg


@dataclass
class EpisodeStart:
    """What ``begin_episode`` reports: the task, the seed actually used and the sketch ids."""

    task: str
    seed: int
    sketch: np.ndarray


class LayoutPublisher:
    """Publishers of one domain's layout topics, with one method per contract position."""

    def __init__(self, node: Node, domain: DomainLayout) -> None:
        self.node = node
        self.domain = domain
        self.observation = node.create_publisher(Float32MultiArray, layout.OBSERVATION, SIM_QOS)
        self.subtask = node.create_publisher(Int32, layout.SUBTASK, SIM_QOS)
        self.action = node.create_publisher(action_msg_type(domain), layout.ACTION, SIM_QOS)
        self.sketch = node.create_publisher(Int32MultiArray, layout.SKETCH, SIM_QOS)
        self.episode = node.create_publisher(DiagnosticArray, layout.EPISODE, SIM_QOS)

    def _stamp(self) -> Any:
        return self.node.get_clock().now().to_msg()

    def episode_start(self, index: int, start: EpisodeStart) -> None:
        sketch = ",".join(str(int(i)) for i in np.asarray(start.sketch).ravel())
        values = {
            layout.KEY_EPISODE: index, layout.KEY_TASK: start.task, layout.KEY_SEED: start.seed,
            layout.KEY_SKETCH: sketch,
        }  # fmt: skip
        self.episode.publish(episode_marker(self._stamp(), layout.EPISODE_START, values))
        self.sketch.publish(sketch_msg(start.sketch))

    def publish_observation(self, obs: np.ndarray) -> None:
        self.observation.publish(observation_msg(obs))

    def publish_subtask(self, subtask: int) -> None:
        self.subtask.publish(Int32(data=int(subtask)))

    def publish_action(self, action: Any) -> None:
        self.action.publish(action_msg(self.domain, action))

    def episode_end(self, index: int, start: EpisodeStart, steps: int, success: bool) -> None:
        values = {
            layout.KEY_EPISODE: index, layout.KEY_TASK: start.task, layout.KEY_SEED: start.seed,
            layout.KEY_STEPS: steps, layout.KEY_SUCCESS: "true" if success else "false",
        }  # fmt: skip
        self.episode.publish(episode_marker(self._stamp(), layout.EPISODE_END, values))


class SimNode(Node):
    """Base of a sim node: parameters, publishers, expert/policy state machine.  Subclass hooks below."""

    def __init__(self, node_name: str, domain: DomainLayout, domain_params: Sequence[ParamSpec] = ()) -> None:
        super().__init__(node_name)
        self.domain = domain
        # A domain may override a common parameter (dial_sim's real-time rate): the last row wins.
        self.param_table = ParamTable({s.name: s for s in (*COMMON_PARAMS, *domain_params)}.values())
        self.params = self.param_table.declare(self)
        self.mode: str = self.params["mode"]
        self.rate: float = float(self.params["rate"])
        self.policy_timeout: float = float(self.params["policy_timeout"])
        self.publisher = LayoutPublisher(self, domain)
        self.finished = False
        self.episode_index = 0
        self.step_index = 0
        self._start: EpisodeStart | None = None  # None between episodes
        self._pending_action: Any = None
        self._awaiting_since = 0.0
        # Policy mode: a policy also answers the final observation; wait (briefly) for that answer and
        # drop it, so that it is never executed as the answer to the next episode's first observation.
        self._drain_until = 0.0
        self._ready_since: float | None = None
        self._wait_topic_names = self._wait_topics()
        if self.mode == "policy":
            self.create_subscription(action_msg_type(domain), layout.CMD_ACTION, self._on_cmd_action, SIM_QOS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._timer = self.create_timer(self._tick_period(), self._tick)

    # --- hooks -------------------------------------------------------------------------------------
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
                self._timer = self.create_timer(self._tick_period(), self._tick)
            elif p.name == "policy_timeout":
                self.policy_timeout = float(p.value)
        return SetParametersResult(successful=True)

    # --- state machine -------------------------------------------------------------------------------
    def _wait_topics(self) -> list[str]:
        known = list(layout.topic_types(self.domain))
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
        if self._ready_since is None and all(
            p.get_subscription_count() >= wanted for p in self._waited_publishers()
        ):
            # The subscriber's other topics are matched a moment later: settle before publishing.
            self._ready_since = time.monotonic() + _SETTLE_S
        return False

    def _waited_publishers(self) -> list[Any]:
        resolved = {self.resolve_topic_name(t) for t in self._wait_topic_names}
        return [p for p in self.publishers if p.topic_name in resolved]

    def _publish_observation(self, final: bool = False) -> None:
        self.publisher.publish_observation(self.observation())
        self.publish_step_extras(final)
        self._pending_action = None  # a command sent before this observation is stale
        self._awaiting_since = time.monotonic()

    def _start_episode(self) -> None:
        seed = derive_seed(int(self.params["seed"]), self.episode_index)
        self._start = self.begin_episode(self.episode_index, seed)
        self.step_index = 0
        self.publisher.episode_start(self.episode_index, self._start)
        self._publish_observation()

    def _end_episode(self) -> None:
        assert self._start is not None
        self.publisher.episode_end(self.episode_index, self._start, self.step_index, self.episode_success())
        self._start = None
        self.episode_index += 1
        total = int(self.params["episodes"])
        if total and self.episode_index >= total:
            self.finished = True
            self._timer.cancel()

    def _take_step(self, action: Any) -> None:
        self.publisher.publish_subtask(self.current_subtask())
        self.publisher.publish_action(action)
        over = self.apply_action(action)
        self.step_index += 1
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
                if time.monotonic() < self._drain_until:
                    return  # still waiting for the policy's answer to the final observation
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


def run_sim_node(factory: Callable[[], SimNode], args: list[str] | None = None, name: str = "sim") -> int:
    """The ``main()`` idiom: init, spin until finished or shut down, exit code 2 on bad parameters."""
    rclpy.init(args=args)
    node: SimNode | None = None
    code = 0
    try:
        node = factory()
        while rclpy.ok() and not node.finished:
            rclpy.spin_once(node, timeout_sec=0.1)
        deadline = time.monotonic() + _LINGER_S
        while rclpy.ok() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
    except ParameterError as exc:
        print(f"{name}: {exc}", file=sys.stderr, flush=True)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
