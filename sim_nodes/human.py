"""Human-like demonstrations: what a person at the controls adds to a scripted demonstration.

The two sims offer two demonstrators (``demonstrator: expert | human``).  ``human`` runs the same
expert and perturbs it the way a teleoperated demonstration differs from a scripted one
(docs/craft.md §2.6, docs/dial.md §3.9):

* **pauses** of random length at any step (``pause_rate`` per step) and **hesitations** when a
  subtask begins (``hesitation_rate`` per subtask), ``pause_steps`` = (shortest, longest) steps;
* **variable speed** (Dial): a tempo factor per subtask, log-uniform in ``speed_range``;
* **overshoot and correction**: Craft one cell too far, then back (per move); Dial past the key's
  approach point, then back to it (per subtask);
* **wrong moves undone**: Craft a step away and back (per move); Dial the approach of a
  neighbouring key first, then the right one (per subtask);
* **sidetracks at subtask changes** (``boundary_rate`` per subtask change, default 0): where people
  make them (pauses, exploration and mistakes cluster at task-phase changes): at a change the
  demonstrator pauses ``pause_steps`` and then corrects itself on the new subtask's first move (an
  overshoot or a wrong move undone, in the ratio of ``overshoot_rate`` to ``wrong_move_rate``, even
  when both are 0).  :data:`BOUNDARY_MODE` moves the random pauses there (``pause_rate=0``,
  ``boundary_rate=0.5``: half the changes);
* **sensor noise**: Gaussian, standard deviation ``sensor_noise``, on every recorded observation
  (and Dial's joint states); the demonstrator itself acts on the true state;
* **dropped and duplicated observation messages** (``drop_rate``, ``duplicate_rate`` per message,
  never the first or the final observation of an episode): ``extras['observation_copies']`` ``[T+1]``
  says how many times each observation is published (0, 1 or 2); ``ompn_collect`` and the sim nodes
  obey it, the episode's arrays stay complete.

Labels stay exact: a step carries the subtask in progress in the env, so a pause or a wrong move
belongs to the subtask it interrupts.  Everything is drawn from the episode seed (its own streams),
so a human-like episode is as reproducible as an expert one.  ``extras['human_events']`` counts
what happened (``pauses``, ``hesitations``, ``pause_steps``, ``overshoots``, ``wrong_moves``,
``sidetracks``, ``opportunities_*``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ompn_ros.data.episode import OBSERVATION_COPIES, Episode

DEMONSTRATORS = ("expert", "human")
EVENTS_KEY = "human_events"
_BEHAVIOUR_STREAM = 0x4855
_RECORDING_STREAM = 0x4856
_RATES = ("pause_rate", "hesitation_rate", "overshoot_rate", "wrong_move_rate", "drop_rate", "duplicate_rate",
          "boundary_rate")
BOUNDARY_MODE = ("pause_rate=0", "boundary_rate=0.5")
"""Pauses where people make them: the human-like defaults with the random pauses moved to subtask
changes, half of which carry a sidetrack (a pause, then a correction); ``--demonstrator human`` with
these parameters (docs/craft.md §2.6, docs/dial.md §3.9)."""


class HumanLikeError(ValueError):
    """A human-like demonstrator parameter is invalid; the message names it and what is allowed."""


def _fail(name: str, allowed: str, value: object) -> None:
    raise HumanLikeError(f"human-like parameter '{name}' must be {allowed}, got {value!r}")


@dataclass(frozen=True)
class HumanLike:
    """The perturbations of the human-like demonstrator (module docstring); defaults per domain in
    :func:`human_defaults`."""

    pause_rate: float = 0.01
    hesitation_rate: float = 0.3
    pause_steps: tuple[int, int] = (5, 25)
    speed_range: tuple[float, float] = (0.6, 1.6)
    overshoot_rate: float = 0.3
    wrong_move_rate: float = 0.15
    sensor_noise: float = 0.002
    drop_rate: float = 0.01
    duplicate_rate: float = 0.01
    boundary_rate: float = 0.0

    def __post_init__(self) -> None:
        for name in (*_RATES, "sensor_noise"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                _fail(name, "a number in [0, 1]", value)
        for first, second in (("drop_rate", "duplicate_rate"), ("overshoot_rate", "wrong_move_rate")):
            pair = (getattr(self, first), getattr(self, second))
            if sum(pair) > 1.0:
                _fail(f"{first}' + '{second}", "at most 1 together", pair)
        lo, hi = self.pause_steps
        if not (isinstance(lo, int) and isinstance(hi, int) and 1 <= lo <= hi <= 500):
            _fail("pause_steps", "MIN:MAX, ints with 1 <= MIN <= MAX <= 500", self.pause_steps)
        if not 0.1 <= self.speed_range[0] <= self.speed_range[1] <= 10.0:
            _fail("speed_range", "MIN:MAX with 0.1 <= MIN <= MAX <= 10", self.speed_range)

    def pause_length(self, rng: np.random.Generator) -> int:
        lo, hi = self.pause_steps
        return int(rng.integers(lo, hi + 1))

    def as_dict(self) -> dict[str, Any]:
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}
        if not self.boundary_rate:
            del out["boundary_rate"]  # off: the settings of demonstrations made before it existed
        return out

    def correction(self, rng: np.random.Generator) -> str:
        """The correction of a sidetrack: 'overshoot' or 'wrong', in the ratio of ``overshoot_rate`` to
        ``wrong_move_rate`` (even odds when both are 0)."""
        total = self.overshoot_rate + self.wrong_move_rate
        share = self.overshoot_rate / total if total > 0 else 0.5
        return "overshoot" if rng.random() < share else "wrong"


_DEFAULTS = {
    # Dial: 25 Hz continuous control; a pause of 5-25 steps is 0.2-1 s.
    "dial": HumanLike(),
    # Craft: one cell per step, 64 steps at most per episode: short pauses, no tempo (one cell a step).
    "craft": HumanLike(pause_rate=0.03, hesitation_rate=0.3, pause_steps=(1, 3), speed_range=(1.0, 1.0),
                       overshoot_rate=0.05, wrong_move_rate=0.05, sensor_noise=0.02),
}  # fmt: skip


def human_defaults(domain: str) -> HumanLike:
    """The human-like demonstrator's default parameters of ``domain`` ('craft' or 'dial')."""
    if domain not in _DEFAULTS:
        raise HumanLikeError(f"no human-like demonstrator for domain '{domain}'; known: {sorted(_DEFAULTS)}")
    return _DEFAULTS[domain]


def _parse_value(name: str, text: str, default: Any) -> Any:
    try:
        if isinstance(default, tuple):
            parts = text.replace(",", ":").split(":")
            if len(parts) != 2:
                raise ValueError
            kind = type(default[0])
            return (kind(parts[0]), kind(parts[1]))
        return float(text)
    except ValueError:
        shape = "MIN:MAX" if isinstance(default, tuple) else "a number"
        raise HumanLikeError(f"human-like parameter '{name}': cannot read {text!r} as {shape}") from None


def parse_human(domain: str, items: Sequence[str] = ()) -> HumanLike:
    """``domain``'s defaults with ``items`` (``'name=value'``, ranges as ``MIN:MAX``) applied.

    Raises :class:`HumanLikeError` naming the first unknown or bad parameter.
    """
    base = human_defaults(domain)
    known = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
    changes: dict[str, Any] = {}
    for item in items:
        name, sep, text = str(item).partition("=")
        name = name.strip()
        if not sep or name not in known:
            raise HumanLikeError(f"human-like parameter {item!r}: expected NAME=VALUE with NAME one of "
                                 f"{sorted(known)}")  # fmt: skip
        changes[name] = _parse_value(name, text.strip(), known[name])
    return dataclasses.replace(base, **changes)


def behaviour_rng(seed: int) -> np.random.Generator:
    """The RNG of the human-like behaviour (pauses, tempo, detours) of the episode ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), _BEHAVIOUR_STREAM]))


def new_events() -> dict[str, int]:
    names = ("pauses", "hesitations", "pause_steps", "overshoots", "wrong_moves", "opportunities_pause",
             "opportunities_hesitation", "opportunities_detour", "sidetracks",
             "opportunities_sidetrack")  # fmt: skip
    return dict.fromkeys(names, 0)


def record_faults(episode: Episode, human: HumanLike, seed: int) -> Episode:
    """Add sensor noise to the recorded observations (and joint states) and choose, per observation
    message, whether it is dropped or duplicated (``extras['observation_copies']``); in place."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _RECORDING_STREAM]))
    if human.sensor_noise > 0:
        obs = episode.observations
        obs += rng.normal(0.0, human.sensor_noise, obs.shape).astype(obs.dtype)
        for key in ("joint_position", "joint_velocity"):
            if key in episode.extras:
                values = np.asarray(episode.extras[key], dtype=np.float64)
                episode.extras[key] = values + rng.normal(0.0, human.sensor_noise, values.shape)
    copies = np.ones(len(episode.observations), dtype=np.int64)
    draw = rng.random(len(copies))
    inner = np.zeros(len(copies), dtype=bool)
    inner[1:-1] = True  # the first and the final observation are always published once
    copies[inner & (draw < human.drop_rate)] = 0
    copies[inner & (draw >= human.drop_rate) & (draw < human.drop_rate + human.duplicate_rate)] = 2
    episode.extras[OBSERVATION_COPIES] = copies
    return episode
