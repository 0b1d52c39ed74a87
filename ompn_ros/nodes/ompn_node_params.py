"""The parameters of ``ompn_node`` (one :class:`~ompn_ros.ros.params.ParamSpec` row each) and its QoS.

When a change applies (``ompn_ros.ros.params``):

* live, from the next step: ``detector_*``, ``done_threshold``, ``sketch`` (the default sketch),
  ``warn_throttle``, ``max_stamp_lead``, ``clock_jump_back``, ``clock_jump_forward``, ``clock_stall``;
* at the next ``configure`` (refused while active, with the way out): ``checkpoint``, ``domain``,
  ``obs_source``, ``joint_fields``, ``observation_spec``, ``obs_dim``, ``action_type``, ``sketch_mode``,
  ``qos_depth``, ``obs_qos``, ``boundary_replay``, ``diagnostics_period``, ``torch_threads``,
  ``episode_gap``, ``idle_s``, ``idle_speed``, ``joint_names``, ``joint_merge``;
* at start-up only: ``auto_start``, ``executor``.

QoS of the observation and joint-state subscriptions (``obs_qos``): ``best_effort`` (default) receives
from RELIABLE and BEST_EFFORT publishers alike (``sensor_msgs/JointState`` is usually published
BEST_EFFORT); ``reliable`` matches RELIABLE publishers only; ``sensor_data`` is rclpy's sensor profile
(BEST_EFFORT, depth 5).

Observation from several topics (``observation_spec``, :mod:`ompn_ros.nodes.ompn_node_obs`): inline
YAML (``{step_topic: ..., fields: [...]}``) or a YAML file path, in the form of
:mod:`ompn_ros.data.obs.spec`; relative topics resolve in the node's namespace.  When set, it replaces
``obs_source``/``joint_fields``; every spec topic is subscribed with the ``obs_qos`` QoS.  On the command
line rcl reads ``-p`` values as YAML, so give a file path, or quote the mapping as a YAML string:
``-p 'observation_spec:="{step_topic: ..., fields: [...]}"'``; in a params file either form works.

``~/boundary`` durability (``boundary_replay``): ``last`` (default) = RELIABLE + TRANSIENT_LOCAL with
depth 1, so a subscriber that joins late receives the last boundary event only; ``none`` = VOLATILE,
late subscribers receive nothing old.  Live subscribers get every event either way.
"""

from __future__ import annotations

from typing import Any, Final

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from ompn_ros import layout
from ompn_ros.detect.online import ALL_MODES, MAX_LAG, MAX_OFFSET
from ompn_ros.layout import JOINT_FIELDS
from ompn_ros.nodes.ompn_node_idle import idle_speed_rule
from ompn_ros.nodes.ompn_node_obs import spec_rule
from ompn_ros.ros.params import ParamSpec

OBS_SOURCES: Final = ("array", "joint_state")
EXECUTORS: Final = ("single", "events")
OBS_QOS: Final = ("best_effort", "reliable", "sensor_data")
BOUNDARY_REPLAY: Final = ("last", "none")
MIN_EPISODE_GAP: Final = 0.01  # seconds; the silence timer polls every quarter of the gap
BOUNDARY_QOS_DEPTH: Final = layout.BOUNDARY_QOS["none"].depth  # history of a VOLATILE ~/boundary writer


def _sketch_rule(value: Any) -> str | None:
    ids = list(value)
    if ids == [-1]:
        return None
    if not ids or any(int(v) < 0 for v in ids):
        return f"{ids} is not [-1] (no default sketch) or a list of ids >= 0"
    return None


def _gap_rule(value: Any) -> str | None:
    gap = float(value)
    return None if gap == 0.0 or gap >= MIN_EPISODE_GAP else f"must be 0 (off) or >= {MIN_EPISODE_GAP} s"


def _fields_rule(value: Any) -> str | None:
    return None if list(value) else f"must name at least one of {list(JOINT_FIELDS)}"


SPECS: Final = (
    ParamSpec("domain", "", "'craft' | 'dial' | '' (checks sizes, picks the shipped checkpoint)",
              choices=("", *layout.DOMAINS), apply="configure"),
    ParamSpec("checkpoint", "", "checkpoint directory, or an ensemble directory (ensemble.json); "
              "'' = the shipped one for 'domain'", apply="configure"),
    ParamSpec("obs_source", "array", "'array' (observation topic) | 'joint_state'", choices=OBS_SOURCES,
              apply="configure"),
    ParamSpec("joint_fields", ["position"], "JointState arrays concatenated into the observation",
              choices=JOINT_FIELDS, apply="configure", check=_fields_rule),
    ParamSpec("joint_names", [""], "obs_source 'joint_state': joints in observation order, by name ([''] = "
              "the message's order)", apply="configure"),
    ParamSpec("joint_merge", 0.0, "obs_source 'joint_state': merge the messages of several publishers on "
              "joint_states by joint name; each joint's latest value may be this many seconds older than the "
              "step, a message naming the first of joint_names is a step (the reader's merge_s; 0 = one "
              "publisher)", float_range=(0.0, 1e6), apply="configure"),
    ParamSpec("observation_spec", "", "observation assembled from several topics: inline YAML or a YAML "
              "file ('' = obs_source alone; see ompn_ros.data.obs.spec)", apply="configure", check=spec_rule),
    ParamSpec("obs_dim", 0, "expected observation size (0 = from domain/checkpoint)",
              int_range=(0, 1_000_000), apply="configure"),
    ParamSpec("action_type", "", "expected action type", choices=("", "discrete", "continuous"),
              apply="configure"),
    ParamSpec("sketch_mode", "", "expected model sketch mode", choices=("", "none", "sum"),
              apply="configure"),
    ParamSpec("sketch", [-1], "default sketch (subtask ids) for sketch models; [-1] = none",
              apply="live", check=_sketch_rule),
    ParamSpec("detector_high", 0.5, "a boundary run starts when the score > high",
              float_range=(0.0, 1.0), apply="live"),
    ParamSpec("detector_hysteresis", 0.0, "a run ends when score <= high - hysteresis",
              float_range=(0.0, 1.0), apply="live"),
    ParamSpec("detector_min_segment_length", 1, "minimum steps per detected segment",
              int_range=(1, 100_000), apply="live"),
    ParamSpec("detector_mode", "falling_edge", "boundary commit rule; 'hsmm': the duration decoder of the "
              "checkpoint's detector.json (detector_high = the posterior that the subtask has ended; higher: "
              "later, surer boundaries); 'head': its learned boundary head (detector_high = the head's "
              "probability, detector_min_segment_length = the fewest steps between boundaries); "
              "'head_hsmm': the duration decoder weighing the head (detector_high as for 'hsmm'); switching "
              "to or from 'hsmm', 'head' or 'head_hsmm' inside an episode applies from the next one",
              choices=ALL_MODES,
              apply="live"),
    ParamSpec("detector_lag", 0, "hsmm, head_hsmm: a boundary is published at least detector_lag + 1 steps "
              "after its step (more when the evidence is weak); head: detector_lag + 1 steps after it (the "
              "episode end decides its last steps); changed inside an episode: from the next one",
              int_range=(0, MAX_LAG), apply="live"),
    ParamSpec("detector_offset", 0, "threshold modes: report a boundary this many steps before the step the "
              "rule gives (not before the previous boundary); it is still published when the rule commits it",
              int_range=(0, MAX_OFFSET), apply="live"),
    ParamSpec("detector_force_first_step_low", True, "treat step 0's score as 0", apply="live"),
    ParamSpec("done_threshold", 0.5, "discrete: publish done (= action_dim) when pi_end exceeds this",
              float_range=(0.0, 1.0), apply="live"),
    ParamSpec("auto_start", True, "configure and activate at start-up"),
    ParamSpec("qos_depth", layout.PER_STEP_QOS.depth, "depth of the input and per-step output queues",
              int_range=(1, 100_000), apply="configure"),
    ParamSpec("obs_qos", "best_effort", "QoS of the observation / joint_states subscription",
              choices=OBS_QOS, apply="configure"),
    ParamSpec("boundary_replay", "last", "what a late ~/boundary subscriber receives",
              choices=BOUNDARY_REPLAY, apply="configure"),
    ParamSpec("diagnostics_period", 1.0, "seconds between /diagnostics messages",
              float_range=(0.01, 3600.0), apply="configure"),
    ParamSpec("warn_throttle", 1.0, "seconds between bad-input warnings", float_range=(0.0, 3600.0),
              apply="live"),
    ParamSpec("max_stamp_lead", 60.0, "seconds an input stamp may lie ahead of the node's clock "
              "(0 = no check)", float_range=(0.0, 1e9), apply="live"),
    ParamSpec("clock_jump_back", 1.0, "seconds back in time that count as a clock restart (a new "
              "episode) rather than an out-of-order message", float_range=(0.0, 1e9), apply="live"),
    ParamSpec("clock_jump_forward", 60.0, "use_sim_time: seconds /clock may leap ahead between two messages "
              "before it counts as a clock restart (a new episode, counted, warned; 0 = no check)",
              float_range=(0.0, 1e9), apply="live"),
    ParamSpec("clock_stall", 5.0, "use_sim_time: seconds of wall time without /clock advancing that are "
              "reported as a stall (once per stall: a warning and the clock_stalls counter; 0 = no check)",
              float_range=(0.0, 1e6), apply="live"),
    ParamSpec("episode_gap", 0.0, "seconds between two step stamps, or without a step, that end an "
              "episode and start the next, for streams without episode markers (the reader's "
              "split: gaps / time_gap; 0 = off)", float_range=(0.0, 1e6), apply="configure",
              check=_gap_rule),
    ParamSpec("idle_s", 0.0, "seconds the robot must be idle to end an episode, for streams without "
              "episode markers whose driver keeps publishing between demonstrations (the reader's split: "
              "idle; idle steps are held, then stepped or trimmed; 0 = off)", float_range=(0.0, 1e6),
              apply="configure"),
    ParamSpec("idle_speed", "auto", "idle_s: a step is idle when its speed is below this: with obs_source "
              "joint_state the joint speed in rad/s (positions' change per second, velocities as measured), "
              "else any element's change per second; 'auto' or a number >= 0. auto: the value the "
              "checkpoint's training read used (idle_speed.json beside it), else derived from the first 10 s "
              "of the stream (held until then); the node logs the value", apply="configure",
              check=idle_speed_rule, dynamic=True),
    ParamSpec("executor", "events", "callback executor", choices=EXECUTORS),
    ParamSpec("torch_threads", 1, "torch intra-op threads", int_range=(1, 64), apply="configure"),
)  # fmt: skip


def input_qos(kind: str, depth: int) -> QoSProfile:
    """QoS of the observation / joint-state subscription (and of every ``observation_spec`` topic) for
    ``obs_qos`` = ``kind``."""
    if kind == "sensor_data":
        return qos_profile_sensor_data
    reliability = ReliabilityPolicy.RELIABLE if kind == "reliable" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=depth, reliability=reliability, history=HistoryPolicy.KEEP_LAST)


def boundary_qos(replay: str) -> QoSProfile:
    """QoS of ``~/boundary`` for ``boundary_replay`` = ``replay`` (module docstring;
    ``layout.BOUNDARY_QOS``, which annotated bags record too)."""
    qos = layout.BOUNDARY_QOS["last" if replay == "last" else "none"]
    return QoSProfile(
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if qos.transient_local else DurabilityPolicy.VOLATILE,
        history=HistoryPolicy.KEEP_LAST,
    )


def policy_kind_name(kind: Any) -> str:
    """Readable name of a ``QoSPolicyKind`` (e.g. 'RELIABILITY')."""
    return str(getattr(kind, "name", kind)).replace("RMW_QOS_POLICY_", "")
