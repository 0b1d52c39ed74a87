"""The topic layout: the single source of truth for names, types and vector sizes.

Every piece that touches ROS topics or bags (the sim nodes, ``bag_recorder``, ``ompn_collect``,
the bag reader and ``ompn_node``) imports these constants and never repeats them.  This module is
ROS-free: types are given as ROS 2 type names (``pkg/msg/Type``), the spelling both ``rosbags``
and ``rclpy`` understand.

Per-step publishing order of a sim (the *step contract*)::

    episode start marker (DiagnosticArray, message='start', with sketch)    once per episode
    sketch                                                                   once per episode
    for t in 0..T-1:
        observation_t, [joint_states_t], subtask_t, action_t                 in this order
    observation_T   (the final observation: no action, no subtask; the 'done' step)
    episode end marker (DiagnosticArray, message='end')

The observation topic is the step clock.  A message on any other per-step topic belongs to the
latest observation published before it.  Bags written by ``ompn_collect`` use synthetic stamps
(``EPISODE_GAP_NS`` between episodes, ``STEP_NS`` between steps, ``TOPIC_OFFSET_NS`` between the
topics of one step); live recordings use the publisher's source timestamp, so the publish order
above is kept exactly in both routes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

# --- message type names -------------------------------------------------------------------------
FLOAT32_ARRAY: Final = "std_msgs/msg/Float32MultiArray"
INT32_ARRAY: Final = "std_msgs/msg/Int32MultiArray"
INT32: Final = "std_msgs/msg/Int32"
STRING: Final = "std_msgs/msg/String"
JOINT_STATE: Final = "sensor_msgs/msg/JointState"
DIAGNOSTIC_ARRAY: Final = "diagnostic_msgs/msg/DiagnosticArray"
EPISODE_MARKER_TYPE: Final = "ompn_interfaces/msg/EpisodeMarker"  # the typed episode marker
FLOAT64_ARRAY: Final = "std_msgs/msg/Float64MultiArray"  # with the next four: a user's observation topics
FLOAT32: Final = "std_msgs/msg/Float32"
FLOAT64: Final = "std_msgs/msg/Float64"
WRENCH_STAMPED: Final = "geometry_msgs/msg/WrenchStamped"
POSE_STAMPED: Final = "geometry_msgs/msg/PoseStamped"

# --- topics published by both sims (relative names: they follow the node's namespace) ------------
OBSERVATION: Final = "observation"  # Float32MultiArray, dim label 'obs', the policy input
ACTION: Final = "action"  # the action label of the step: Float32MultiArray (dial) or Int32 (craft).
# In expert mode this is the demonstrator's noise-free action (the behaviour-cloning target; DART noise
# is added only to what is executed). In policy mode it is the received cmd_action that was executed.
SUBTASK: Final = "subtask"  # Int32: ground-truth subtask ordinal within the episode (0-based)
SKETCH: Final = "sketch"  # Int32MultiArray: subtask ids of the episode's task, once per episode
EPISODE_MARKER: Final = "episode_marker"  # ompn_interfaces/msg/EpisodeMarker: episode start / end
EPISODE: Final = "episode"  # deprecated: DiagnosticArray episode marker (keys below), read for one release
JOINT_STATES: Final = "joint_states"  # JointState, dial only (9 joints, stamped with sim time)
RENDER: Final = "render"  # String: human-readable ANSI rendering (craft)

# --- topics consumed by sims in policy mode, published by ompn_node -------------------------------
CMD_ACTION: Final = "cmd_action"  # same type as ACTION

# --- ompn_node private outputs ---------------------------------------------------------------------
PI: Final = "~/pi"  # Float32MultiArray: n slot probs (lowest slot first), then E[pos], then pi_end
PI_LABEL: Final = "pi_slots_then_expected_position_then_pi_end"  # ~/pi's one dimension: all n + 2 values
STATE: Final = "~/state"  # ompn_interfaces/msg/SubtaskState: ~/pi with named fields, one per step
BOUNDARY: Final = "~/boundary"  # ompn_interfaces/msg/SubtaskBoundary boundary event
DIAGNOSTICS: Final = "/diagnostics"  # DiagnosticArray node health (counters)


@dataclass(frozen=True)
class OutputQos:
    """The QoS ``ompn_node`` offers on one output topic: RELIABLE and KEEP_LAST always, ``depth`` deep,
    TRANSIENT_LOCAL or VOLATILE.  The node builds its publishers from these values and annotated bags
    record them as the topic's ``offered_qos_profiles``, so a player that honours them (``ros2 bag
    play``) offers what the node offers."""

    depth: int
    transient_local: bool = False


PER_STEP_QOS: Final = OutputQos(depth=100)  # ~/pi, ~/state, cmd_action (depth: parameter qos_depth)
BOUNDARY_QOS: Final = {  # ~/boundary by parameter boundary_replay
    "last": OutputQos(depth=1, transient_local=True),  # a late subscriber gets the last event
    "none": OutputQos(depth=100),  # VOLATILE: nothing old is replayed
}

# --- episode marker keys (DiagnosticStatus.name == EPISODE_STATUS_NAME) ----------------------------
EPISODE_STATUS_NAME: Final = "episode"
EPISODE_START: Final = "start"  # DiagnosticStatus.message
EPISODE_END: Final = "end"
KEY_EPISODE: Final = "episode"  # running episode index of the publisher (int)
KEY_TASK: Final = "task"  # task name, e.g. 'makebed' or 'dial'
KEY_SEED: Final = "seed"  # episode seed (int)
KEY_SKETCH: Final = "sketch"  # comma-separated subtask ids
KEY_STEPS: Final = "steps"  # end marker: number of real steps T
KEY_SUCCESS: Final = "success"  # end marker: 'true' | 'false'

# --- JointState fields a reader or node may take vectors from (in message order) -------------------
JOINT_FIELDS: Final = ("position", "velocity", "effort")

# --- what a subtask topic holds (bag reader ``labels``) -------------------------------------------
LABELS_ORDINAL: Final = "ordinal"  # Int32 per step: 0-based subtask ordinal within the episode (ours)
LABELS_ID: Final = "id"  # Int32 per step: a skill id; ordinals follow from changes between steps
LABELS_BOUNDARY: Final = "boundary"  # an event topic: one message at the last step of each subtask
LABELS_NONE: Final = "none"  # no labels are read
LABEL_KINDS: Final = (LABELS_ORDINAL, LABELS_ID, LABELS_BOUNDARY, LABELS_NONE)

# --- synthetic stamps used by ompn_collect (nanoseconds) ------------------------------------------
STEP_NS: Final = 40_000_000  # 25 Hz
TOPIC_OFFSET_NS: Final = 1_000  # spacing of the topics within one step
EPISODE_GAP_NS: Final = 1_000_000_000


@dataclass(frozen=True)
class DomainLayout:
    """Sizes and action type of one simulated domain."""

    name: str
    obs_dim: int
    action_type: str  # 'discrete' | 'continuous'
    action_dim: int  # number of env actions (discrete, excluding done) or vector size
    action_msg: str
    has_joint_states: bool
    step_topics: tuple[str, ...]  # per-step topics in publish order (observation first)
    sketch_vocab: int  # sketch ids lie in 0..sketch_vocab-1 (Craft: subtask ids 1..8; Dial: digits 0..9)


CRAFT: Final = DomainLayout(
    name="craft",
    obs_dim=1075,
    action_type="discrete",
    action_dim=5,
    action_msg=INT32,
    has_joint_states=False,
    step_topics=(OBSERVATION, SUBTASK, ACTION),
    sketch_vocab=9,
)

DIAL: Final = DomainLayout(
    name="dial",
    obs_dim=39,
    action_type="continuous",
    action_dim=9,
    action_msg=FLOAT32_ARRAY,
    has_joint_states=True,
    step_topics=(OBSERVATION, JOINT_STATES, SUBTASK, ACTION),
    sketch_vocab=10,
)

DOMAINS: Final = {d.name: d for d in (CRAFT, DIAL)}


def topic_types(domain: DomainLayout) -> dict[str, str]:
    """Map every topic a sim of ``domain`` publishes to its type name."""
    types = {
        OBSERVATION: FLOAT32_ARRAY,
        ACTION: domain.action_msg,
        SUBTASK: INT32,
        SKETCH: INT32_ARRAY,
        EPISODE_MARKER: EPISODE_MARKER_TYPE,
        EPISODE: DIAGNOSTIC_ARRAY,  # deprecated, published for one release beside EPISODE_MARKER
    }
    if domain.has_joint_states:
        types[JOINT_STATES] = JOINT_STATE
    if domain.name == "craft":
        types[RENDER] = STRING
    return types


def resolve_topic(name: str, namespace: str = "/") -> str:
    """Absolute topic name of a layout topic (relative names follow ``namespace``)."""
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/")
    return f"{ns.rstrip('/')}/{name}"
