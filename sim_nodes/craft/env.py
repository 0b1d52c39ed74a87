"""Gymnasium wrapper of the Craft world: ``gymnasium.make('ompn_ros/Craft-v0', task=..., full_obs=...)``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sim_nodes.craft.features import N_FEATURES, world_features
from sim_nodes.craft.render import render_ansi, render_rgb
from sim_nodes.craft.sketch import sketch_ids
from sim_nodes.craft.world import MAX_STEPS, N_ACTIONS, CraftWorld, get_task

ENV_ID = "ompn_ros/Craft-v0"


class CraftEnv(gym.Env[np.ndarray, int]):
    """Craft with the 1075-float observation, dense reward per completed subtask and a 64-step limit.

    ``reset(seed=s)`` draws the map from ``np.random.default_rng(s)`` (reproducible, unlike the
    authors' OS-seeded RNG); without a seed the RNG stream continues across episodes.  ``terminated``
    = goal item held; ``truncated`` = ``max_steps`` reached.  DONE (5) is a no-op, as in the authors' env.
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}  # noqa: RUF012 (gymnasium API)

    def __init__(
        self,
        task: str = "makebed",
        full_obs: bool = True,
        render_mode: str | None = None,
        max_steps: int = MAX_STEPS,
    ) -> None:
        self.task = get_task(task)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.full_obs = bool(full_obs)
        self.render_mode = render_mode
        self.max_steps = max_steps
        self.world = CraftWorld(self.task)
        self.sketch = sketch_ids(self.task)
        self.observation_space = gym.spaces.Box(0.0, 255.0, (N_FEATURES,), np.float32)
        self.action_space = gym.spaces.Discrete(N_ACTIONS)  # type: ignore[assignment]
        self._map_rng: np.random.Generator | None = None
        self.episode_seed: int | None = None

    def _obs(self) -> np.ndarray:
        return world_features(self.world, full_obs=self.full_obs)

    def _info(self) -> dict[str, Any]:
        n = len(self.task.sketch)
        return {
            "sketch_index": self.world.sketch_index,
            "subtask": min(self.world.sketch_index, n - 1),
            "success": self.world.all_subtasks_done,
            "seed": self.episode_seed,
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._map_rng = np.random.default_rng(seed)
        elif self._map_rng is None:
            self._map_rng = np.random.default_rng()
        self.episode_seed = seed
        self.world.reset(self._map_rng)
        return self._obs(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        subtask = min(self.world.sketch_index, len(self.task.sketch) - 1)
        result = self.world.step(action)
        truncated = not result.terminated and self.world.steps >= self.max_steps
        info = self._info()
        info["step_subtask"] = subtask  # the ground-truth ordinal of the step just taken
        return self._obs(), result.reward, result.terminated, truncated, info

    def render(self) -> Any:
        if self.render_mode == "ansi":
            return render_ansi(self.world)
        if self.render_mode == "rgb_array":
            return render_rgb(self.world)
        return None
