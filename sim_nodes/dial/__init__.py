"""Dial: a Kinova JACO arm presses a sketch of 4 digits on a phone keypad (MuJoCo).

Rebuild of the TACO/OMPN "jacopinpad" domain (docs/dial.md) on dm_control's JACO model, which is
loaded from the installed ``dm_control`` package.  Importing this package registers the gymnasium
env ``ompn_ros/Dial-v0`` and defaults ``MUJOCO_GL`` to ``egl`` (offscreen rendering) when mujoco
has not been imported yet.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from sim_nodes.dial.env import (
    ACTION_DIM,
    ENV_ID,
    OBS_DIM,
    ORIGINAL_GYM_TOLERANCE,
    PRESS_TOLERANCE,
    SKETCH_LENGTH,
    DialConfigError,
    DialEnv,
    register,
    sample_sketch,
)
from sim_nodes.dial.expert import (
    DEFAULT_NOISE,
    JOINT_STATE_NAMES,
    DialExpert,
    generate_episode,
    generate_episodes,
)

DIGITS: tuple[int, ...] = tuple(range(10))
"""The sketch vocabulary: subtask id k = press the key labelled k."""
SUBTASK_NAMES: tuple[str, ...] = tuple(f"press_{d}" for d in DIGITS)

register()

__all__ = [
    "ACTION_DIM",
    "DEFAULT_NOISE",
    "DIGITS",
    "ENV_ID",
    "JOINT_STATE_NAMES",
    "OBS_DIM",
    "ORIGINAL_GYM_TOLERANCE",
    "PRESS_TOLERANCE",
    "SKETCH_LENGTH",
    "SUBTASK_NAMES",
    "DialConfigError",
    "DialEnv",
    "DialExpert",
    "generate_episode",
    "generate_episodes",
    "register",
    "sample_sketch",
]
