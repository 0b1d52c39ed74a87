"""``dial_sim``: the Dial task (JACO arm, phone keypad) as a ROS 2 node.

Publishes in the step contract of :mod:`ompn_ros.layout` (``layout.DIAL.step_topics``)::

    episode (start marker), sketch,
    (observation_t [39], joint_states_t, subtask_t, action_t [9]) * T, observation_T, joint_states_T,
    episode (end marker)

``joint_states`` (``sensor_msgs/JointState``) carries the names, positions, velocities and efforts
of the 9 joints (``sim_nodes.dial.JOINT_STATE_NAMES``) stamped with the simulation time (seconds
of simulated time since the node started, continuous across episodes).  Effort is the actuator
torque applied during the step that led to the observation.

Parameters (besides the common ones of :mod:`sim_nodes.ros_common`: mode, seed, episodes,
policy_timeout, wait_for_subscribers):

* ``rate`` (float, default 25.0 Hz = real time; 0 = as fast as possible);
* ``sketch`` (int array of 4 digits, no immediate repeat; unset or empty = drawn from the seed);
* ``press_tolerance`` (float, L1 metres, default 0.01; the original gym env used 0.1);
* ``noise`` (float >= 0, expert DART noise scale, default ``DEFAULT_NOISE``);
* ``max_steps_per_subtask`` (int, per-subtask timeout in steps, default 500);
* ``permute_labels`` (bool, per-episode label permutation, default false).

Expert mode runs exactly the demonstration ``generate_episode(derive_seed(seed, i), ...)`` live
(the same one ``generate_episodes(n, seed=seed)`` yields, including retries), so live recordings
and ``ompn_collect`` bags agree.  ``action`` carries the expert's noise-free action (the training
label, as in :class:`~ompn_ros.data.episode.Episode`); the env executes it plus DART noise, so set
``noise:=0.0`` to make the published action exactly the executed one.  In policy mode the node
executes each ``cmd_action`` (9 floats in [-1, 1]) and publishes it as ``action``; while no
command arrives the simulation does not advance (the arm is held) and a throttled warning is
logged every ``policy_timeout`` seconds.
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from ompn_ros import layout
from ompn_ros.nodes.params import ParameterError, ParamSpec
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
from sim_nodes.ros_common import SIM_QOS, EpisodeStart, SimNode, run_sim_node

NODE_NAME = "dial_sim"
DIAL_PARAMS = (
    ParamSpec("rate", 25.0, "steps per second (25 = real time, 0 = as fast as possible)",
              float_range=(0.0, 10000.0), apply="live"),
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


class DialSim(SimNode):
    """Dial sim node: expert demonstrations or closed-loop policy execution."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, layout.DIAL, DIAL_PARAMS)
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
        self.rollout = DemoRollout(self.env, noise=self.noise, permute_labels=self.permute)
        self.joint_pub = self.create_publisher(JointState, layout.JOINT_STATES, SIM_QOS)
        self._time_offset = 0.0  # simulated seconds of the finished episodes
        self.get_logger().info(
            f"dial_sim: mode={self.mode} rate={self.rate} Hz episodes={self.params['episodes'] or 'forever'} "
            f"seed={self.params['seed']} sketch={'seeded' if self.sketch is None else self.sketch.tolist()} "
            f"press_tolerance={self.env.press_tolerance} noise={self.noise}"
        )

    # --- SimNode hooks -----------------------------------------------------------------------------
    def begin_episode(self, index: int, seed: int) -> EpisodeStart:
        if index > 0:
            self._time_offset += float(self.env.data.time)
        sketch = episode_sketch(seed) if self.sketch is None else self.sketch
        run_seed = seed
        if self.mode == "expert":  # find the attempt generate_episode keeps, then run it live
            demo = generate_episode(
                seed, sketch=sketch.tolist(), noise=self.noise, permute_labels=self.permute, env=self.env
            )
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
        return self.rollout.done

    def episode_success(self) -> bool:
        return bool(self.rollout.terminated)

    def publish_step_extras(self, final: bool) -> None:
        msg = JointState()
        sim_time = self._time_offset + float(self.env.data.time)
        sec = int(sim_time)
        msg.header.stamp.sec = sec
        msg.header.stamp.nanosec = round((sim_time - sec) * 1e9) % 1_000_000_000
        msg.name = list(JOINT_STATE_NAMES)
        msg.position = self.env.joint_position.tolist()
        msg.velocity = self.env.joint_velocity.tolist()
        msg.effort = self.env.joint_effort.tolist()
        self.joint_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Console script ``dial_sim``."""
    return run_sim_node(DialSim, args, NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
