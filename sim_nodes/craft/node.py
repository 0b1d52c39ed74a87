"""``craft_sim``: the Craft world as a ROS 2 node (topics and step contract from :mod:`ompn_ros.layout`).

Parameters (besides the common ones of :mod:`sim_nodes.ros_common`: mode, rate, seed, episodes,
policy_timeout, wait_for_subscribers, wait_topics, publish_clock, episode_pause, demonstrator, human):

* ``task`` (string, one of the 13 Craft tasks, default 'makebed');
* ``full_obs`` (bool, default true).

Expert mode publishes exactly the episodes of ``generate_episodes(n, task=..., full_obs=..., seed=seed)``
(successful expert demonstrations, failed maps are regenerated from derived seeds) by replaying them in
the live env; with ``demonstrator:=human`` those of ``generate_human_episode`` (their noisy
observations, some dropped or published twice).  Every observation is followed by its ANSI rendering
on ``render``.

Simulated time advances by ``layout.STEP_NS`` (40 ms) per step and 1 s between episodes, the spacing of
``ompn_collect`` bags; with ``publish_clock:=true`` (default) it is published on ``/clock`` and stamps the
episode markers.
"""

from __future__ import annotations

import sys

import numpy as np
from std_msgs.msg import String

from ompn_ros import layout
from ompn_ros.data.messages import encode_string
from ompn_ros.ros.params import ParamSpec
from ompn_ros.ros.run import run_node
from sim_nodes.craft.env import CraftEnv
from sim_nodes.craft.expert import generate_episode
from sim_nodes.craft.human import generate_human_episode
from sim_nodes.craft.render import render_ansi
from sim_nodes.craft.world import TASKS
from sim_nodes.ros_common import SIM_QOS, EpisodeStart, SimNode, serve_sim, sim_params

NODE_NAME = "craft_sim"
ABOUT = f"{NODE_NAME}: a simulator publishing the ompn_ros topic layout."
CRAFT_PARAMS = (
    ParamSpec("task", "makebed", "Craft task name", choices=tuple(TASKS)),
    ParamSpec("full_obs", True, "full observation (global view) instead of the 5x5 window only"),
)


class CraftSim(SimNode):
    """Craft sim node: expert demonstrations or closed-loop policy execution."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, layout.CRAFT, CRAFT_PARAMS)
        self.task: str = self.params["task"]
        self.full_obs: bool = bool(self.params["full_obs"])
        self.env = CraftEnv(self.task, full_obs=self.full_obs)
        self.render_pub = self.create_publisher(String, layout.RENDER, SIM_QOS)
        self._expert_actions = np.zeros(0, dtype=np.int64)
        self._last_obs: np.ndarray | None = None
        self.get_logger().info(
            f"craft_sim: task={self.task} full_obs={self.full_obs} mode={self.mode} rate={self.rate} Hz "
            f"episodes={self.params['episodes'] or 'forever'} seed={self.params['seed']}"
        )

    def begin_episode(self, index: int, seed: int) -> EpisodeStart:
        if self.mode == "expert":
            if self.human is None:
                demo = generate_episode(seed, task=self.task, full_obs=self.full_obs)
            else:
                demo = generate_human_episode(seed, self.human, task=self.task, full_obs=self.full_obs)
                self.demo = demo
            seed = demo.seed
            self._expert_actions = demo.actions
        self._last_obs, _ = self.env.reset(seed=seed)
        return EpisodeStart(task=self.task, seed=seed, sketch=self.env.sketch)

    def observation(self) -> np.ndarray:
        assert self._last_obs is not None
        return self._last_obs

    def current_subtask(self) -> int:
        return min(self.env.world.sketch_index, len(self.env.task.sketch) - 1)

    def expert_action(self) -> int:
        return int(self._expert_actions[self.step_index])

    def apply_action(self, action: int) -> bool:
        self._last_obs, _, terminated, truncated, _ = self.env.step(int(action))
        over = terminated or truncated
        if self.mode == "expert" and self.step_index + 1 >= len(self._expert_actions):
            over = True  # the demonstration is complete (it always ends with the goal made)
        return bool(over)

    def episode_success(self) -> bool:
        return self.env.world.all_subtasks_done

    def publish_step_extras(self, final: bool) -> None:
        self.render_pub.publish(encode_string(render_ansi(self.env.world)))


def main(args: list[str] | None = None) -> int:
    """Console script ``craft_sim``."""
    return run_node(NODE_NAME, CraftSim, args, about=ABOUT, params=sim_params(CRAFT_PARAMS), serve=serve_sim)


if __name__ == "__main__":
    sys.exit(main())
