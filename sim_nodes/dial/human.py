"""The human-like Dial demonstrator (docs/dial.md §3.9): the scripted controller with pauses,
hesitations, a tempo per subtask, overshoots and wrong keys approached, then corrected; then sensor
noise and dropped or duplicated observation messages.

It acts on the reference the PID follows (:class:`~sim_nodes.dial.expert.DialExpert`):

* a pause holds the reference where it is for ``pause_steps`` steps (the arm stays put);
* each subtask draws a tempo factor (log-uniform in ``speed_range``) for the joint speed limit;
* once per subtask, when its approach begins, it may take a **detour** first: an *overshoot* aims
  15-35 % past the key's approach posture (joint space, at most 0.15 rad per joint), a *wrong key*
  aims at the approach posture of one of the three keys nearest the right one; it holds there
  :data:`DETOUR_HOLD` steps and then approaches the right key.  No press can complete on a detour:
  the env counts only the target key, and approach points lie above the keys;
* a sidetrack (``boundary_rate``) at a subtask change (not the first) holds the reference
  ``pause_steps`` and makes that subtask's detour certain.

Labels come from the env (the subtask in progress), so a detour belongs to its subtask.
"""

from __future__ import annotations

import numpy as np

from ompn_ros.data.episode import Episode
from sim_nodes.dial.env import DialEnv
from sim_nodes.dial.expert import DialExpert, ExpertGains, generate_episode
from sim_nodes.human import EVENTS_KEY, HumanLike, behaviour_rng, new_events, record_faults

DETOUR_HOLD = 3
OVERSHOOT_FRACTION = (0.15, 0.35)
OVERSHOOT_MAX_RAD = 0.15
WRONG_KEY_CHOICES = 3


class HumanDialExpert(DialExpert):
    """The Dial controller with the human-like perturbations of ``human`` (module docstring)."""

    def __init__(
        self, env: DialEnv, gains: ExpertGains, joint_speed: float, human: HumanLike, seed: int
    ) -> None:
        self.human = human
        self.rng = behaviour_rng(seed)
        self.base_speed = float(joint_speed)
        self.events = new_events()
        super().__init__(env, gains, joint_speed=joint_speed)

    def reset(self) -> None:
        super().reset()
        self.pause_left = 0
        self.subtask_seen = -1
        self.planned: str | None = None
        self.detour: np.ndarray | None = None
        self.detour_hold = 0
        self.approach_seen = False

    def _pause(self, kind: str) -> None:
        length = self.human.pause_length(self.rng)
        self.events[kind] += 1
        self.events["pause_steps"] += length
        self.pause_left += length

    def _new_subtask(self) -> None:
        h, rng = self.human, self.rng
        self.subtask_seen = self.env.subtasks_done
        lo, hi = h.speed_range
        self.joint_speed = self.base_speed * float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        self.events["opportunities_hesitation"] += 1
        if rng.random() < h.hesitation_rate:
            self._pause("hesitations")
        self.events["opportunities_detour"] += 1
        draw = rng.random()
        wrong_upto = h.overshoot_rate + h.wrong_move_rate
        self.planned = "overshoot" if draw < h.overshoot_rate else "wrong" if draw < wrong_upto else None
        self.approach_seen = False
        if h.boundary_rate > 0 and self.env.subtasks_done > 0:
            self.events["opportunities_sidetrack"] += 1
            if rng.random() < h.boundary_rate:
                self.events["sidetracks"] += 1
                self._pause("pauses")
                self.planned = h.correction(rng)

    def _start_detour(self) -> None:
        digit = self.env.target_digit
        approach = self.targets.approach
        if self.planned == "overshoot":
            over = self.rng.uniform(*OVERSHOOT_FRACTION) * (approach[digit] - self.q_ref)
            over[6:] = 0.0
            largest = float(np.max(np.abs(over[:6])))
            if largest > OVERSHOOT_MAX_RAD:
                over *= OVERSHOOT_MAX_RAD / largest
            self.detour = approach[digit] + over
            self.events["overshoots"] += 1
        elif self.planned == "wrong":
            xyz = self.targets.approach_xyz
            order = np.argsort(np.abs(xyz - xyz[digit]).sum(axis=1))
            wrong = int(order[1 + int(self.rng.integers(WRONG_KEY_CHOICES))])
            self.detour = approach[wrong].copy()
            self.events["wrong_moves"] += 1
        self.detour_hold = 0

    def _update_phase(self) -> None:
        super()._update_phase()
        if self.detour is not None and self.phase == "press":
            self.phase = "approach"  # the detour first; the press follows the corrected approach

    def act(self) -> np.ndarray:
        if self.env.subtasks_done != self.subtask_seen:
            self._new_subtask()
        if self.pause_left == 0:
            self.events["opportunities_pause"] += 1
            if self.rng.random() < self.human.pause_rate:
                self._pause("pauses")
        if self.pause_left > 0:
            self.pause_left -= 1
            return self._torque()  # the reference is held
        phase = self.phase
        self._update_phase()
        if self.phase != phase:
            self.integral[:] = 0.0
        if self.phase == "approach" and not self.approach_seen:
            self.approach_seen = True
            self._start_detour()
        if self.detour is None:
            self._move_reference(self._goal())
        else:
            self._move_reference(self.detour)
            if float(np.max(np.abs(self.detour - self.q_ref))) < 1e-9:
                self.detour_hold += 1
                if self.detour_hold >= DETOUR_HOLD:
                    self.detour = None
        return self._torque()


class HumanDialFactory:
    """A ``make_expert`` for :class:`~sim_nodes.dial.expert.DemoRollout`; keeps the last expert built."""

    def __init__(self, human: HumanLike) -> None:
        self.human = human
        self.last: HumanDialExpert | None = None

    def __call__(self, env: DialEnv, gains: ExpertGains, joint_speed: float, seed: int) -> DialExpert:
        self.last = HumanDialExpert(env, gains, joint_speed, self.human, seed)
        return self.last


def generate_human_episode(seed: int, human: HumanLike, **options: object) -> Episode:
    """A human-like demonstration (``options`` as :func:`~sim_nodes.dial.expert.generate_episode`),
    with sensor noise and ``extras['observation_copies']`` (:func:`sim_nodes.human.record_faults`)."""
    factory = HumanDialFactory(human)
    episode = generate_episode(seed, make_expert=factory, **options)  # type: ignore[arg-type]
    assert factory.last is not None
    episode.extras[EVENTS_KEY] = dict(factory.last.events)
    episode.extras["demonstrator"] = "human"
    return record_faults(episode, human, seed)
