"""``dial_sim``: the Dial task (JACO arm, phone keypad) as a ROS 2 node.

Two profiles (parameter ``profile``):

* ``ompn`` (default): the topic layout of :mod:`ompn_ros.layout`, in the step contract
  (``layout.DIAL.step_topics``)::

      episode (start marker), sketch,
      (observation_t [39], joint_states_t, subtask_t, action_t [9]) * T, observation_T, joint_states_T,
      episode (end marker)

* ``robot``: only what a real arm driver and its task layer would publish, for trying the tools on
  "someone else's robot" (expert mode only)::

      (jaco/joint_states_t, jaco/skill_id_t, jaco/effort_command_t) * T, jaco/joint_states_T,
      then a pause of at least 1 s (``episode_pause``) before the next episode

  ``jaco/skill_id`` (``std_msgs/Int32``, reliable) is the digit being pressed (an id, not an ordinal);
  ``jaco/effort_command`` (``std_msgs/Float64MultiArray`` as ros2_control's effort controllers take it, or
  ``Float32MultiArray`` with ``effort_command_type:=float32``; dimension ``effort``, reliable) is the
  torque command executed during the step (N·m, DART noise included).  No episode markers, no sketch, no
  observation vector: episodes are told apart by the pauses.  The names are relative (they follow the
  node's namespace) and can be remapped (``-r jaco/joint_states:=/my_arm/joint_states``).

``joint_states`` (``sensor_msgs/JointState``, sensor-data QoS: best effort, depth 5, like a driver;
``joint_states_qos:=reliable`` for RELIABLE-only subscribers, and for a lossless recording at
``rate:=0``, where a best-effort subscriber misses some of the bursts) carries the names, positions,
velocities and efforts of the 9 joints (``sim_nodes.dial.JOINT_STATE_NAMES``).  Effort is the actuator torque
applied during the step that led to the observation.  Its stamp, like every stamp of the sim, is the
simulated time (25 Hz steps of 40 ms MuJoCo time, 1 s or ``episode_pause`` between episodes, published
on ``/clock``); with ``publish_clock:=false`` the node clock instead (see :mod:`sim_nodes.ros_common`).

Parameters (besides the common ones of :mod:`sim_nodes.ros_common`: mode, seed, episodes,
policy_timeout, wait_for_subscribers, wait_topics, publish_clock, episode_pause, demonstrator, human):

* ``rate`` (float, default 25.0 Hz = real time; 0 = as fast as possible);
* ``profile`` (``ompn`` | ``robot``, default ``ompn``);
* ``joint_states_qos`` (``sensor_data`` | ``reliable``, default ``sensor_data``);
* ``effort_command_type`` (``float64`` | ``float32``, default ``float64``; robot profile);
* ``sketch`` (int array of 4 digits, no immediate repeat; unset or empty = drawn from the seed);
* ``press_tolerance`` (float, L1 metres, default 0.01; the original gym env used 0.1);
* ``noise`` (float >= 0, expert DART noise scale, default ``DEFAULT_NOISE``);
* ``max_steps_per_subtask`` (int, per-subtask timeout in steps, default 500);
* ``permute_labels`` (bool, per-episode label permutation, default false).

Expert mode runs exactly the demonstration ``generate_episode(derive_seed(seed, i), ...)`` live
(the same one ``generate_episodes(n, seed=seed)`` yields, including retries), so live recordings
and ``ompn_collect`` bags agree.  ``action`` carries the expert's noise-free action (the training
label, as in :class:`~ompn_ros.data.episode.Episode`); the env executes it plus DART noise, so set
``noise:=0.0`` to make the published action exactly the executed one.  With ``demonstrator:=human``
it runs ``generate_human_episode`` live (docs/dial.md §3.9) and publishes that episode's recorded,
noisy observations and joint states, each as often as its ``observation_copies`` say.  In policy mode the node
executes each ``cmd_action`` (9 floats in [-1, 1]) and publishes it as ``action``; while no
command arrives the simulation does not advance (the arm is held) and a throttled warning is
logged every ``policy_timeout`` seconds.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.event_handler import PublisherEventCallbacks, QoSOfferedIncompatibleQoSInfo
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_policy_name_from_kind
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray, Float64MultiArray, Int32

from ompn_ros import layout
from ompn_ros.data.messages import (
    encode_float32_array,
    encode_float64_array,
    encode_int32,
    encode_joint_state,
)
from ompn_ros.ros.params import ParameterError, ParamSpec
from ompn_ros.ros.run import run_node
from sim_nodes import derive_seed
from sim_nodes.dial.env import (
    MAX_STEPS_PER_SUBTASK,
    PRESS_TOLERANCE,
    SKETCH_LENGTH,
    DialConfigError,
    DialEnv,
    validate_sketch,
)
from sim_nodes.dial.expert import (
    DEFAULT_NOISE,
    JOINT_STATE_NAMES,
    DemoRollout,
    episode_sketch,
    generate_episode,
)
from sim_nodes.dial.human import HumanDialFactory, generate_human_episode
from sim_nodes.dial.scene import FRAME_SKIP
from sim_nodes.ros_common import SENSOR_QOS, SIM_QOS, EpisodeStart, SimNode, Streams, serve_sim, sim_params

NODE_NAME = "dial_sim"
ABOUT = f"{NODE_NAME}: a simulator publishing the ompn_ros topic layout."
PROFILES = ("ompn", "robot")
JOINT_STATES_QOS = {"sensor_data": SENSOR_QOS, "reliable": SIM_QOS}
ROBOT_JOINT_STATES = "jaco/joint_states"
ROBOT_SKILL_ID = "jaco/skill_id"
ROBOT_EFFORT_COMMAND = "jaco/effort_command"
EFFORT_TYPES = {"float64": Float64MultiArray, "float32": Float32MultiArray}
ROBOT_MIN_PAUSE_S = 1.0  # the robot profile's episodes are split by pauses of at least this long
DIAL_PARAMS = (
    ParamSpec("rate", 25.0, "steps per second (25 = real time, 0 = as fast as possible)",
              float_range=(0.0, 10000.0), apply="live"),
    ParamSpec("profile", "ompn", "'ompn': the package's topic layout; 'robot': only a real arm's topics"
              " (jaco/joint_states, jaco/skill_id, jaco/effort_command), episodes split by pauses",
              choices=PROFILES),
    ParamSpec("joint_states_qos", "sensor_data", "QoS of the JointState publisher",
              choices=tuple(JOINT_STATES_QOS)),
    ParamSpec("effort_command_type", "float64", "robot profile: std_msgs/Float64MultiArray or"
              " Float32MultiArray on jaco/effort_command", choices=tuple(EFFORT_TYPES)),
    ParamSpec("sketch", Parameter.Type.INTEGER_ARRAY,
              "4 digits to press (no immediate repeat); unset/empty = drawn from the episode seed"),
    ParamSpec("press_tolerance", PRESS_TOLERANCE, "L1 distance (m) of the finger reference to a press point",
              float_range=(1e-4, 1.0)),
    ParamSpec("noise", DEFAULT_NOISE, "expert DART noise scale (normalised action units)",
              float_range=(0.0, 1.0)),
    ParamSpec("max_steps_per_subtask", MAX_STEPS_PER_SUBTASK, "per-subtask timeout in steps",
              int_range=(1, 1_000_000)),
    ParamSpec("permute_labels", False, "permute the digit labels every episode (OMPN dataset variant)"),
)  # fmt: skip


class RobotStreams:
    """The robot profile's per-step topics: a skill id per step, no markers, sketch or observation.

    (``jaco/joint_states`` is published by the node's step extras, ``jaco/effort_command`` after each
    executed step: the command is known only once the env has applied it.)
    """

    def __init__(self, node: Node, skill_id: Callable[[], int]) -> None:
        self.skill_id = skill_id
        self.skill_pub = node.create_publisher(Int32, ROBOT_SKILL_ID, SIM_QOS)

    def topic_names(self) -> list[str]:
        return [ROBOT_JOINT_STATES, ROBOT_SKILL_ID, ROBOT_EFFORT_COMMAND]

    def episode_start(self, index: int, start: EpisodeStart, stamp_ns: int) -> None:
        pass

    def observation(self, obs: np.ndarray) -> None:
        pass

    def subtask(self, ordinal: int) -> None:
        self.skill_pub.publish(encode_int32(self.skill_id()))

    def action(self, action: Any) -> None:
        pass

    def episode_end(self, index: int, start: EpisodeStart, steps: int, success: bool, stamp_ns: int) -> None:
        pass


class DialSim(SimNode):
    """Dial sim node: expert demonstrations or closed-loop policy execution."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, layout.DIAL, DIAL_PARAMS)
        self.profile: str = self.params["profile"]
        if self.profile == "robot" and self.mode != "expert":
            raise ParameterError("profile", "'robot' runs the expert only (use mode:=expert)")
        raw_sketch = self.params["sketch"]
        self.sketch: np.ndarray | None = None
        if raw_sketch is not None and len(raw_sketch) > 0:
            try:
                self.sketch = validate_sketch(list(raw_sketch), SKETCH_LENGTH)
            except DialConfigError as exc:
                raise ParameterError("sketch", str(exc)) from None
        self.noise = float(self.params["noise"])
        self.permute = bool(self.params["permute_labels"])
        self.env = DialEnv(
            press_tolerance=float(self.params["press_tolerance"]),
            max_steps_per_subtask=int(self.params["max_steps_per_subtask"]),
        )
        self.step_ns = round(float(self.env.model.opt.timestep) * FRAME_SKIP * 1e9)  # 40 ms of MuJoCo time
        self.rollout = DemoRollout(self.env, noise=self.noise, permute_labels=self.permute)
        robot = self.profile == "robot"
        self.joint_pub = self.create_publisher(
            JointState, ROBOT_JOINT_STATES if robot else layout.JOINT_STATES,
            JOINT_STATES_QOS[self.params["joint_states_qos"]],
            event_callbacks=PublisherEventCallbacks(incompatible_qos=self._on_incompatible_qos),
        )  # fmt: skip
        effort_type = self.params["effort_command_type"]
        self._encode_effort = encode_float64_array if effort_type == "float64" else encode_float32_array
        self.effort_pub = (
            self.create_publisher(EFFORT_TYPES[effort_type], ROBOT_EFFORT_COMMAND, SIM_QOS) if robot else None
        )
        self.get_logger().info(
            f"dial_sim: profile={self.profile} mode={self.mode} rate={self.rate} Hz "
            f"episodes={self.params['episodes'] or 'forever'} seed={self.params['seed']} "
            f"sketch={'seeded' if self.sketch is None else self.sketch.tolist()} "
            f"press_tolerance={self.env.press_tolerance} noise={self.noise} "
            f"publish_clock={self.publish_clock}"
        )

    def _on_incompatible_qos(self, info: QoSOfferedIncompatibleQoSInfo) -> None:
        policy = qos_policy_name_from_kind(info.last_policy_kind)
        self.get_logger().warning(
            f"a subscriber of {self.joint_pub.topic_name} requests a QoS this publisher does not offer"
            f" ({policy}) and receives nothing: subscribe with best effort (sensor data QoS) or start"
            f" {NODE_NAME} with joint_states_qos:=reliable"
        )

    # --- SimNode hooks -----------------------------------------------------------------------------
    def make_streams(self) -> Streams:
        if self.params["profile"] == "robot":
            return RobotStreams(self, lambda: self.env.target_digit)
        return super().make_streams()

    def min_episode_pause(self) -> float:
        return ROBOT_MIN_PAUSE_S if self.params["profile"] == "robot" else 0.0

    def begin_episode(self, index: int, seed: int) -> EpisodeStart:
        sketch = episode_sketch(seed) if self.sketch is None else self.sketch
        run_seed = seed
        if self.mode == "expert":  # find the attempt generate_episode keeps, then run it live
            options: dict[str, Any] = {"sketch": sketch.tolist(), "noise": self.noise,
                                       "permute_labels": self.permute, "env": self.env}  # fmt: skip
            if self.human is None:
                demo = generate_episode(seed, **options)
            else:  # published from its recorded (noisy) rows; the live run executes the same actions
                demo = self.demo = generate_human_episode(seed, self.human, **options)
                self.rollout.make_expert = HumanDialFactory(self.human)
            attempt = int(demo.extras["attempt"])
            run_seed = seed if attempt == 0 else derive_seed(seed, attempt, stream=1)
        self.rollout.start(run_seed, sketch)
        return EpisodeStart(task="dial", seed=seed, sketch=sketch)

    def observation(self) -> np.ndarray:
        return self.env.observation()

    def current_subtask(self) -> int:
        return min(self.env.subtasks_done, self.env.sketch_length - 1)

    def expert_action(self) -> np.ndarray:
        return self.rollout.expert_action().astype(np.float32)

    def apply_action(self, action: np.ndarray) -> bool:
        self.rollout.execute(np.asarray(action, dtype=np.float64), add_noise=self.mode == "expert")
        if self.effort_pub is not None:
            self.effort_pub.publish(self._encode_effort(self.env.joint_effort, label="effort"))
        return self.rollout.done

    def episode_success(self) -> bool:
        return bool(self.rollout.terminated)

    def publish_step_extras(self, final: bool) -> None:
        env = self.env
        position, velocity = env.joint_position, env.joint_velocity
        copies = 1
        if self.demo is not None:  # the human-like demonstrator's noisy joint states
            position = self.demo.extras["joint_position"][self.step_index]
            velocity = self.demo.extras["joint_velocity"][self.step_index]
            copies = self.observation_copies() if self.profile == "robot" else 1  # its observation
        for _ in range(copies):
            self.joint_pub.publish(encode_joint_state(
                self.stamp_ns(), JOINT_STATE_NAMES, position, velocity, env.joint_effort
            ))  # fmt: skip


def main(args: list[str] | None = None) -> int:
    """Console script ``dial_sim``."""
    return run_node(NODE_NAME, DialSim, args, about=ABOUT, params=sim_params(DIAL_PARAMS), serve=serve_sim)


if __name__ == "__main__":
    sys.exit(main())
