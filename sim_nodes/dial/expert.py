"""Scripted Dial demonstrator and the episode generators (docs/dial.md §3, §5.6).

Control law (replaces the original's saturated joint-space PI without IK, docs/dial.md §3.1, which does
not transfer to dm_control's arm, docs/dial.md §5.5).  At 25 Hz, per subtask:

1. **retract** (not for the first subtask): lift the reference point :data:`RETRACT_HEIGHT`
   above the previous key's press point (replaces the original's shoulder "kick", §3.3);
2. **approach**: go to the new key's approach point until the L1 distance < ``approach_tol``;
3. **press**: go to the press point until the env reports the press (L1 < 0.01 m).

Waypoints are joint angles from damped least-squares IK (``mj_jacSite``, :mod:`.targets`).  A
reference ``q_ref`` moves toward the active waypoint at a limited joint speed; the torque is a
joint-space PID with gravity/Coriolis compensation from ``qfrc_bias``::

    tau = Kp (q_ref - q) - Kd qdot + Ki integral(q_ref - q) + qfrc_bias,  a = clip(tau / scale, -1, 1)

DART-style noise (docs/dial.md §3.4): per episode an amount in {0, 2/3, 1} x ``noise`` and a hold time of
``persist`` in 1..5 env steps; every ``persist`` steps a new N(0, sigma) vector is drawn with
``sigma = amount`` (normalised action units) and joint 1 gets an extra U(0, noise/3).  The env
executes ``clip(a + noise)``; the episode records the noise-free ``a``.  Deviation: the original
held noise for 5-29 *physics* steps (0.01-0.06 s) and drew sigma relative to its asymmetric ctrl
box; here the noise acts at the 25 Hz control rate.

Calibration (docs/dial.md §3.8): the reference's top joint speed is drawn per episode, log-uniform in
``ExpertGains.joint_speed_range`` = [0.38, 1.8] rad/s (an operator "tempo"; in the original the
spread came from friction stick-slip and the noise amount).  Measured on seeds 0..1399 with the
defaults (noise 0.1, no retries): 1400/1400 succeed; length mean 204.0, std 63.3, min 110, 5th pct
130, median 188, 95th pct 325, max 450 steps (original: 205.6, 66.2, 101, 125, 183, 330, 360 on 200
demos); per subtask mean 51.0, min 21, max 134 (original 51, 6.5, 134).  The shortest subtasks are
longer than the original's because every subtask after the first begins with an explicit lift.

The ground-truth subtask ordinal recorded at step t is the subtask being worked on when action t
is chosen, so the step that completes a subtask still carries its ordinal (docs/dial.md §3.6).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ompn_ros.data.episode import Episode
from sim_nodes import SEED_MAX, derive_seed
from sim_nodes.dial.env import (
    MAX_STEPS_PER_SUBTASK,
    PRESS_TOLERANCE,
    SKETCH_LENGTH,
    DialConfigError,
    DialEnv,
    sample_sketch,
    validate_sketch,
)
from sim_nodes.dial.scene import FRAME_SKIP, TIMESTEP, TORQUE_SCALE
from sim_nodes.dial.targets import Targets

DEFAULT_NOISE = 0.1
JOINT_STATE_NAMES = (
    "jaco_joint_1", "jaco_joint_2", "jaco_joint_3", "jaco_joint_4", "jaco_joint_5", "jaco_joint_6",
    "jaco_joint_finger_1", "jaco_joint_finger_2", "jaco_joint_finger_3",
)  # fmt: skip
CONTROL_DT = TIMESTEP * FRAME_SKIP


@dataclass(frozen=True)
class ExpertGains:
    """Gains of the demonstrator (per joint: arm 1-6, fingers 1-3)."""

    kp: tuple[float, ...] = (250.0, 250.0, 250.0, 120.0, 120.0, 120.0, 2.0, 2.0, 2.0)
    kd: tuple[float, ...] = (60.0, 60.0, 60.0, 30.0, 30.0, 30.0, 0.2, 0.2, 0.2)
    ki: tuple[float, ...] = (150.0, 150.0, 150.0, 60.0, 60.0, 60.0, 0.0, 0.0, 0.0)
    integral_limit: float = 0.02  # rad·s, anti wind-up; the integral runs in the press phase only
    friction_width: float = 0.004  # rad; Coulomb friction feed-forward = frictionloss * tanh(e / width)
    joint_speed_range: tuple[float, float] = (0.38, 1.8)  # rad/s, per-episode log-uniform tempo
    approach_tol: float = 0.04  # L1 metres (original 0.05)
    retract_tol: float = 0.02  # metres below the retract height that count as lifted


class DartNoise:
    """Persistent Gaussian action noise held for ``persist`` control steps (docs/dial.md §3.4)."""

    def __init__(self, rng: np.random.Generator, noise: float, dim: int = 9) -> None:
        self.rng = rng
        self.noise = float(noise)
        self.amount = float(rng.choice([0.0, 2.0 / 3.0, 1.0])) * self.noise
        self.persist = int(rng.integers(1, 6))
        self.dim = dim
        self._held = np.zeros(dim)
        self._age = self.persist

    def sample(self) -> np.ndarray:
        if self.noise <= 0.0:
            return np.zeros(self.dim)
        if self._age >= self.persist:
            sigma = np.full(self.dim, self.amount)
            sigma[0] += self.rng.uniform(0.0, self.noise / 3.0)
            self._held = self.rng.normal(0.0, sigma)
            self._age = 0
        self._age += 1
        return self._held


class DialExpert:
    """Waypoint IK + joint PID demonstrator acting on a :class:`DialEnv`."""

    def __init__(
        self, env: DialEnv, gains: ExpertGains | None = None, joint_speed: float | None = None
    ) -> None:
        self.env = env
        self.gains = gains or ExpertGains()
        lo, hi = self.gains.joint_speed_range
        self.joint_speed = float(np.sqrt(lo * hi) if joint_speed is None else joint_speed)
        self.targets: Targets = env.targets
        self._kp = np.array(self.gains.kp)
        self._kd = np.array(self.gains.kd)
        self._ki = np.array(self.gains.ki)
        self._friction = np.array(env.model.dof_frictionloss[env.dm.dof_adr])
        self.reset()

    def reset(self) -> None:
        """Call after ``env.reset``."""
        self.q_ref = self.env.joint_position
        self.integral = np.zeros(9)
        self.subtask = self.env.subtasks_done
        self.previous_digit: int | None = None
        self.phase = "approach"

    def _goal(self) -> np.ndarray:
        digit = self.env.target_digit
        if self.phase == "retract":
            assert self.previous_digit is not None
            return self.targets.retract[self.previous_digit]
        if self.phase == "approach":
            return self.targets.approach[digit]
        return self.targets.press[digit]

    def _update_phase(self) -> None:
        env, g = self.env, self.gains
        if env.subtasks_done != self.subtask:  # a press happened: next subtask starts with a lift
            self.previous_digit = int(env.permutation[env.sketch[self.subtask]])
            self.subtask = env.subtasks_done
            self.phase = "retract"
        ref = env.reference_position
        digit = env.target_digit
        if self.phase == "retract":
            assert self.previous_digit is not None
            if ref[2] >= self.targets.retract_xyz[self.previous_digit, 2] - g.retract_tol:
                self.phase = "approach"
        if self.phase == "approach" and np.abs(ref - self.targets.approach_xyz[digit]).sum() < g.approach_tol:
            self.phase = "press"

    def act(self) -> np.ndarray:
        """The noise-free normalised action for the env's current state."""
        phase = self.phase
        self._update_phase()
        if self.phase != phase:
            self.integral[:] = 0.0
        self._move_reference(self._goal())
        return self._torque()

    def _move_reference(self, goal: np.ndarray) -> None:
        """Move ``q_ref`` toward ``goal`` at the joint speed limit."""
        step = goal - self.q_ref
        largest = float(np.max(np.abs(step[:6])))
        limit = self.joint_speed * CONTROL_DT
        if largest > limit:
            step = step * (limit / largest)
        self.q_ref = self.q_ref + step

    def _torque(self) -> np.ndarray:
        """The PID torque toward ``q_ref`` (normalised, clipped)."""
        env = self.env
        q, qd = env.joint_position, env.joint_velocity
        err = self.q_ref - q
        lim = self.gains.integral_limit
        if self.phase == "press":
            self.integral = np.clip(self.integral + err * CONTROL_DT, -lim, lim)
        bias = env.data.qfrc_bias[env.dm.dof_adr]
        friction = self._friction * np.tanh(err / self.gains.friction_width)
        tau = self._kp * err - self._kd * qd + self._ki * self.integral + bias + friction
        return np.clip(tau / TORQUE_SCALE, -1.0, 1.0)


ExpertFactory = Callable[[DialEnv, ExpertGains, float, int], DialExpert]
"""Builds an episode's demonstrator from (env, gains, tempo, attempt seed)."""


def scripted_expert(env: DialEnv, gains: ExpertGains, joint_speed: float, seed: int) -> DialExpert:
    return DialExpert(env, gains, joint_speed=joint_speed)


def episode_sketch(seed: int) -> np.ndarray:
    """The sketch an episode of ``seed`` uses when none is given."""
    return sample_sketch(np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7])))


class DemoRollout:
    """One seeded demonstration, stepped by the caller (used by :func:`generate_episode` and dial_sim).

    ``start(seed, sketch)`` resets the env and draws the episode's tempo, DART noise and (with
    ``permute_labels``) label permutation from ``seed``; each ``step()`` returns
    ``(subtask, clean_action)`` and executes ``clean_action + noise`` in the env.
    """

    def __init__(self, env: DialEnv, *, noise: float = DEFAULT_NOISE, permute_labels: bool = False,
                 gains: ExpertGains | None = None,
                 make_expert: ExpertFactory = scripted_expert) -> None:  # fmt: skip
        if not noise >= 0:
            raise DialConfigError(f"noise must be >= 0, got {noise!r}")
        self.env = env
        self.noise = float(noise)
        self.permute_labels = permute_labels
        self.gains = gains or ExpertGains()
        self.make_expert = make_expert
        self.terminated = self.truncated = False

    def start(self, seed: int, sketch: np.ndarray) -> None:
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD1A1]))
        options: dict[str, object] = {"sketch": sketch}
        if self.permute_labels:
            perm = rng.permutation(10)
            while np.array_equal(perm, np.arange(10)):  # the original excluded the identity (§3.6)
                perm = rng.permutation(10)
            options["permutation"] = perm
        self.env.reset(seed=seed, options=options)
        lo, hi = self.gains.joint_speed_range
        self.joint_speed = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        self.expert = self.make_expert(self.env, self.gains, self.joint_speed, seed)
        self.dart = DartNoise(rng, self.noise)
        self.terminated = self.truncated = False

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated

    def expert_action(self) -> np.ndarray:
        """The noise-free action for the current state (advances the expert's reference)."""
        return self.expert.act()

    def execute(self, clean: np.ndarray, *, add_noise: bool = True) -> np.ndarray:
        """Step the env with ``clean`` (+ DART noise); return the observation."""
        executed = np.clip(clean + self.dart.sample(), -1.0, 1.0) if add_noise else clean
        obs, _, self.terminated, self.truncated, _ = self.env.step(executed)
        return obs


def _attempt(rollout: DemoRollout, seed: int, sketch: np.ndarray) -> Episode:
    env = rollout.env
    rollout.start(seed, sketch)
    obs_rows = [env.observation()]
    pos, vel, eff = [env.joint_position], [env.joint_velocity], [np.zeros(9)]
    actions, labels = [], []
    while not rollout.done:
        clean = rollout.expert_action()
        labels.append(env.subtasks_done)
        actions.append(clean.astype(np.float32))
        obs_rows.append(rollout.execute(clean))
        pos.append(env.joint_position)
        vel.append(env.joint_velocity)
        eff.append(env.joint_effort)
    return Episode(
        observations=np.asarray(obs_rows, dtype=np.float32),
        actions=np.asarray(actions, dtype=np.float32).reshape(-1, 9),
        subtask=np.asarray(labels, dtype=np.int64),
        sketch=sketch.astype(np.int64),
        task="dial",
        seed=seed,
        success=bool(rollout.terminated),
        extras={
            "joint_position": np.asarray(pos, dtype=np.float64),
            "joint_velocity": np.asarray(vel, dtype=np.float64),
            "joint_effort": np.asarray(eff, dtype=np.float64),
            "joint_names": list(JOINT_STATE_NAMES),
            "permutation": env.permutation.copy(),
            "noise_amount": rollout.dart.amount,
            "noise_persist": rollout.dart.persist,
            "joint_speed": rollout.joint_speed,
        },
    )


def generate_episode(
    seed: int,
    *,
    sketch: Sequence[int] | None = None,
    noise: float = DEFAULT_NOISE,
    max_retries: int = 20,
    task: str | None = None,
    permute_labels: bool = False,
    press_tolerance: float = PRESS_TOLERANCE,
    max_steps_per_subtask: int = MAX_STEPS_PER_SUBTASK,
    gains: ExpertGains | None = None,
    env: DialEnv | None = None,
    make_expert: ExpertFactory = scripted_expert,
) -> Episode:
    """One expert demonstration of a 4-digit sketch (see module docstring).

    The sketch is drawn from ``seed`` unless given.  If an attempt times out (a subtask takes
    ``max_steps_per_subtask`` steps), up to ``max_retries`` further attempts run with seeds
    ``derive_seed(seed, k, stream=1)`` and the same sketch; ``extras['attempt']`` is k.
    ``Episode.seed`` is always the requested ``seed``.  If every attempt fails, the last one is
    returned with ``success=False``.  Bad arguments raise :class:`DialConfigError`.

    Extras: ``joint_position``/``joint_velocity``/``joint_effort`` ``[T+1, 9]`` (effort row t =
    actuator torque applied during the step that led to observation t; row 0 is zero),
    ``joint_names``, ``permutation``, ``noise_amount``, ``noise_persist``, ``joint_speed``,
    ``attempt``.  ``make_expert`` builds the demonstrator (:mod:`sim_nodes.dial.human`: human-like).
    """
    if task not in (None, "dial"):
        raise DialConfigError(f"task must be 'dial' (or None) for the Dial domain, got {task!r}")
    if not isinstance(max_retries, int) or max_retries < 0:
        raise DialConfigError(f"max_retries must be an int >= 0, got {max_retries!r}")
    if not 0 <= int(seed) <= SEED_MAX:
        raise DialConfigError(f"seed must be in 0..{SEED_MAX}, got {seed!r}")
    seed = int(seed)
    sketch_arr = episode_sketch(seed) if sketch is None else validate_sketch(sketch, SKETCH_LENGTH)
    if env is None:
        env = DialEnv(press_tolerance=press_tolerance, max_steps_per_subtask=max_steps_per_subtask)
    rollout = DemoRollout(
        env, noise=noise, permute_labels=permute_labels, gains=gains, make_expert=make_expert
    )
    episode = None
    for attempt in range(max_retries + 1):
        attempt_seed = seed if attempt == 0 else derive_seed(seed, attempt, stream=1)
        episode = _attempt(rollout, attempt_seed, sketch_arr)
        episode.seed = seed
        episode.extras["attempt"] = attempt
        if episode.success:
            break
    assert episode is not None
    return episode


def generate_episodes(n: int, *, seed: int = 0, **options: object) -> Iterator[Episode]:
    """``n`` demonstrations; episode i uses ``derive_seed(seed, i)`` like ``dial_sim`` does.

    ``options`` are those of :func:`generate_episode` (one env is reused).
    """
    if not isinstance(n, int) or n < 0:
        raise DialConfigError(f"n must be an int >= 0, got {n!r}")
    if not 0 <= int(seed) <= SEED_MAX:
        raise DialConfigError(f"seed must be in 0..{SEED_MAX}, got {seed!r}")
    env = DialEnv(
        press_tolerance=float(options.pop("press_tolerance", PRESS_TOLERANCE)),  # type: ignore[arg-type]
        max_steps_per_subtask=int(options.pop("max_steps_per_subtask", MAX_STEPS_PER_SUBTASK)),  # type: ignore[call-overload]
    )
    for i in range(n):
        yield generate_episode(derive_seed(int(seed), i), env=env, **options)  # type: ignore[arg-type]
