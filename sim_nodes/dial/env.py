"""Gymnasium environment ``ompn_ros/Dial-v0``: press a sketch of 4 digits on a phone keypad.

Rebuild of TACO/OMPN's ``jacopinpad-v0`` (docs/dial.md §2) on dm_control's JACO arm
(see :mod:`sim_nodes.dial.scene` for the scene and its deviations).

Observation (39 float32, docs/dial.md §2.1):
    ``obs[0:9]``   raw joint angles (rad, unwrapped): arm joints 1-6, fingers 1-3.
    ``obs[9:39]``  for label k = 0..9: ``p_ref - p_press[perm[k]]`` (metres), where ``p_ref`` is
                   the reference site (``arm/hand/pinchsite``) and ``perm`` is the identity unless
                   ``permute_labels`` is on.  Same sign as the original (finger - press point).

Action (9 float32 in [-1, 1]): normalised joint torques, applied for ``FRAME_SKIP`` = 20 physics
steps of 2 ms (25 Hz).  ``torque_i = TORQUE_SCALE[i] * clip(a_i, -1, 1)`` with
``TORQUE_SCALE = (30.5, 30.5, 30.5, 6.8, 6.8, 6.8, 1, 1, 1)`` N·m (dm_control's JACO force limits;
implemented as motor gear with ctrlrange [-1, 1]).  The original used raw, asymmetric ctrl
limits (docs/dial.md §2.2) instead.

Task: a sketch of ``sketch_length`` (default 4) labels, uniform over 0..9 with no immediate repeat
(docs/dial.md §2.5), drawn from the ``reset`` seed.  A press of label k happens when the L1 distance
``|p_ref - p_press[perm[k]]|_1 < press_tolerance``; it is tested on every physics sub-step (on the
pose that sub-step's forward pass computed) and on the pose at the end of the step; after a press
the remaining sub-steps already test the next label (as the original did).
Default tolerance 0.01 m (the demonstrator's threshold; the original gym env used 0.1, exported
as :data:`ORIGINAL_GYM_TOLERANCE`).  Reward is 1 on the step that completes the whole sketch
(``terminated``), else 0; ``truncated`` when one subtask takes ``max_steps_per_subtask`` steps
(default 500, docs/dial.md §2.6).

``info``: ``subtasks_done`` (0..4, the paper's return), ``subtask_index`` (label ordinal being
worked on, = subtasks_done capped at K-1), ``target_label``, ``steps_in_subtask``,
``is_success``, ``sketch``, ``permutation``.

Initial state (docs/dial.md §3.5): the home pose + U(-0.1, 0.1) rad on all 9 joints, joint 1 + U(0, 0.2),
joint 2 - U(0, 0.2), zero velocity (``init_noise=False`` starts exactly at home).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from ompn_ros import validate
from ompn_ros.errors import OMPNError
from sim_nodes.dial.render import make_renderer, render_frame
from sim_nodes.dial.scene import FRAME_SKIP, N_KEYS, TORQUE_SCALE, DialModel, shared_model
from sim_nodes.dial.targets import Targets, shared_targets

ENV_ID = "ompn_ros/Dial-v0"
OBS_DIM = 9 + 3 * N_KEYS
ACTION_DIM = 9
SKETCH_LENGTH = 4
PRESS_TOLERANCE = 0.01
ORIGINAL_GYM_TOLERANCE = 0.1
MAX_STEPS_PER_SUBTASK = 500


class DialConfigError(OMPNError, ValueError):
    """A bad Dial environment/expert argument (the message names it)."""


def sample_sketch(rng: np.random.Generator, length: int = SKETCH_LENGTH) -> np.ndarray:
    """``length`` labels uniform over 0..9, each differing from its predecessor (docs/dial.md §2.5)."""
    out = [int(rng.integers(N_KEYS))]
    while len(out) < length:
        nxt = int(rng.integers(N_KEYS - 1))
        out.append(nxt + 1 if nxt >= out[-1] else nxt)  # uniform over the 9 other labels
    return np.array(out, dtype=np.int64)


def validate_sketch(sketch: Sequence[int], length: int | None = None) -> np.ndarray:
    """Check a user-given sketch: labels in 0..9, no immediate repeat, optional length
    (the package's one sketch validator, :func:`ompn_ros.validate.validate_sketch`)."""
    try:
        return validate.validate_sketch(list(sketch), N_KEYS, length=length, no_immediate_repeat=True)
    except validate.SketchError as exc:
        raise DialConfigError(str(exc)) from None


class DialEnv(gym.Env):
    """The Dial task as a gymnasium environment (see module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}  # noqa: RUF012 (gymnasium API)

    def __init__(
        self,
        *,
        sketch_length: int = SKETCH_LENGTH,
        press_tolerance: float = PRESS_TOLERANCE,
        max_steps_per_subtask: int = MAX_STEPS_PER_SUBTASK,
        permute_labels: bool = False,
        init_noise: bool = True,
        render_mode: str | None = None,
    ) -> None:
        if not isinstance(sketch_length, int) or sketch_length < 1:
            raise DialConfigError(f"sketch_length must be a positive int, got {sketch_length!r}")
        if not press_tolerance > 0:
            raise DialConfigError(f"press_tolerance must be > 0 metres, got {press_tolerance!r}")
        if not isinstance(max_steps_per_subtask, int) or max_steps_per_subtask < 1:
            raise DialConfigError(
                f"max_steps_per_subtask must be a positive int, got {max_steps_per_subtask!r}"
            )
        if render_mode not in (None, "rgb_array"):
            raise DialConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.sketch_length = sketch_length
        self.press_tolerance = float(press_tolerance)
        self.max_steps_per_subtask = max_steps_per_subtask
        self.permute_labels = permute_labels
        self.init_noise = init_noise
        self.render_mode = render_mode
        self.dm: DialModel = shared_model()
        self.targets: Targets = shared_targets()
        self.model = self.dm.model
        self.data = mujoco.MjData(self.model)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)
        self.sketch = np.zeros(sketch_length, dtype=np.int64)
        self.permutation = np.arange(N_KEYS)
        self.subtasks_done = 0
        self.steps_in_subtask = 0
        self._press_xyz = self.data.site_xpos[self.dm.press_sites].copy()
        self._renderer: Any = None

    # --- state access ------------------------------------------------------------------------
    @property
    def reference_position(self) -> np.ndarray:
        """World position of the reference site (copy)."""
        return self.data.site_xpos[self.dm.reference_site].copy()

    @property
    def joint_position(self) -> np.ndarray:
        return self.data.qpos[self.dm.qpos_adr].copy()

    @property
    def joint_velocity(self) -> np.ndarray:
        return self.data.qvel[self.dm.dof_adr].copy()

    @property
    def joint_effort(self) -> np.ndarray:
        """Actuator torque currently applied on the 9 joints (N·m)."""
        return self.data.ctrl * TORQUE_SCALE

    @property
    def target_digit(self) -> int:
        """Physical digit of the current subtask (after the label permutation)."""
        k = min(self.subtasks_done, self.sketch_length - 1)
        return int(self.permutation[self.sketch[k]])

    def observation(self) -> np.ndarray:
        ref = self.data.site_xpos[self.dm.reference_site]
        offsets = ref[None, :] - self._press_xyz[self.permutation]
        return np.concatenate([self.data.qpos[self.dm.qpos_adr], offsets.ravel()]).astype(np.float32)

    def _info(self) -> dict[str, Any]:
        return {
            "subtasks_done": self.subtasks_done,
            "subtask_index": min(self.subtasks_done, self.sketch_length - 1),
            "target_label": int(self.sketch[min(self.subtasks_done, self.sketch_length - 1)]),
            "steps_in_subtask": self.steps_in_subtask,
            "is_success": self.subtasks_done >= self.sketch_length,
            "sketch": self.sketch.copy(),
            "permutation": self.permutation.copy(),
        }

    # --- gymnasium API -----------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode.  ``options``: ``sketch`` (labels), ``permutation`` ([10] ints)."""
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        if options.get("sketch") is not None:
            self.sketch = validate_sketch(options["sketch"], self.sketch_length)
        else:
            self.sketch = sample_sketch(rng, self.sketch_length)
        if options.get("permutation") is not None:
            perm = np.asarray(options["permutation"], dtype=np.int64)
            if sorted(perm.tolist()) != list(range(N_KEYS)):
                raise DialConfigError(f"permutation must be a permutation of 0..9, got {perm.tolist()}")
            self.permutation = perm
        elif self.permute_labels:
            perm = rng.permutation(N_KEYS)
            while np.array_equal(perm, np.arange(N_KEYS)):  # the original excluded the identity
                perm = rng.permutation(N_KEYS)
            self.permutation = perm
        else:
            self.permutation = np.arange(N_KEYS)
        q0 = self.targets.home.copy()
        if self.init_noise:
            q0 += rng.uniform(-0.1, 0.1, 9)
            q0[0] += rng.uniform(0.0, 0.2)
            q0[1] -= rng.uniform(0.0, 0.2)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.dm.qpos_adr] = q0
        mujoco.mj_forward(self.model, self.data)
        self._press_xyz = self.data.site_xpos[self.dm.press_sites].copy()
        self.subtasks_done = 0
        self.steps_in_subtask = 0
        return self.observation(), self._info()

    def _pressed(self) -> bool:
        ref = self.data.site_xpos[self.dm.reference_site]
        return float(np.abs(ref - self._press_xyz[self.target_digit]).sum()) < self.press_tolerance

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (ACTION_DIM,):
            raise DialConfigError(f"action must have {ACTION_DIM} elements, got shape {np.shape(action)}")
        if not np.all(np.isfinite(a)):
            raise DialConfigError(f"action contains non-finite values: {a.tolist()}")
        self.data.ctrl[:] = np.clip(a, -1.0, 1.0)
        done_before = self.subtasks_done
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(self.model, self.data)
            # site_xpos now holds the pose this sub-step started from; the end pose is tested below
            if self._pressed():
                self._complete_subtask()
                if self.subtasks_done >= self.sketch_length:
                    break
        mujoco.mj_kinematics(self.model, self.data)
        if self.subtasks_done < self.sketch_length and self._pressed():
            self._complete_subtask()
        if self.subtasks_done == done_before:
            self.steps_in_subtask += 1
        terminated = self.subtasks_done >= self.sketch_length
        reward = 1.0 if terminated else 0.0
        truncated = (not terminated) and self.steps_in_subtask >= self.max_steps_per_subtask
        return self.observation(), reward, terminated, truncated, self._info()

    def _complete_subtask(self) -> None:
        self.subtasks_done += 1
        self.steps_in_subtask = 0

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = make_renderer(self.model)
        return render_frame(self._renderer, self.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def register() -> None:
    """Register ``ompn_ros/Dial-v0`` with gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="sim_nodes.dial.env:DialEnv")
