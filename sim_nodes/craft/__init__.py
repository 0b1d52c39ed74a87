"""Craft domain (docs/craft.md §1-2): world, features, sketches, expert, gymnasium env (ROS-free)."""

from __future__ import annotations

import gymnasium as gym

from sim_nodes.craft.env import ENV_ID, CraftEnv
from sim_nodes.craft.expert import (
    EpisodeGenerationError,
    ExpertBot,
    PlanningError,
    generate_episode,
    generate_episodes,
    rollout,
)
from sim_nodes.craft.features import (
    N_FEATURES,
    compute_features,
    decode_compact,
    encode_compact,
    world_features,
)
from sim_nodes.craft.sketch import SUBTASK_ID, SUBTASK_NAMES, sketch_ids
from sim_nodes.craft.world import PAPER_TASKS, TASKS, Action, CraftWorld, get_task

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="sim_nodes.craft.env:CraftEnv")

__all__ = [
    "ENV_ID",
    "N_FEATURES",
    "PAPER_TASKS",
    "SUBTASK_ID",
    "SUBTASK_NAMES",
    "TASKS",
    "Action",
    "CraftEnv",
    "CraftWorld",
    "EpisodeGenerationError",
    "ExpertBot",
    "PlanningError",
    "compute_features",
    "decode_compact",
    "encode_compact",
    "generate_episode",
    "generate_episodes",
    "get_task",
    "rollout",
    "sketch_ids",
    "world_features",
]
