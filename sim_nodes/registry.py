"""The simulated domains as ``ompn_ros`` uses them: the one module of ``sim_nodes`` it imports.

Collectors, replay, evaluation and the command-line tools reach the domains through these names
only, so the two packages meet at two small interfaces: this module (ompn_ros -> sim_nodes) and the
public ompn_ros API listed in ``sim_nodes/__init__.py`` (sim_nodes -> ompn_ros).

Importing this module imports both domains (Craft: numpy + gymnasium; Dial: MuJoCo, with
``MUJOCO_GL`` defaulting to ``egl``).
"""

from __future__ import annotations

from typing import Literal, get_args

from ompn_ros.data.episode import Episode
from sim_nodes import SEED_MAX, derive_seed
from sim_nodes.craft import PAPER_TASKS, CraftEnv
from sim_nodes.craft import TASKS as CRAFT_TASKS
from sim_nodes.craft import generate_episode as craft_episode
from sim_nodes.craft.human import generate_human_episode as craft_human_episode
from sim_nodes.dial import DialEnv
from sim_nodes.dial import generate_episode as dial_episode
from sim_nodes.dial.expert import episode_sketch as dial_episode_sketch
from sim_nodes.dial.human import generate_human_episode as dial_human_episode
from sim_nodes.human import DEMONSTRATORS, HumanLike, HumanLikeError, human_defaults, parse_human

Domain = Literal["craft", "dial"]
DOMAINS: tuple[Domain, ...] = get_args(Domain)
DIAL_TASK = "dial"


class UnknownDomainError(ValueError):
    """A domain or task name that no simulator provides."""


def default_tasks(domain: str) -> tuple[str, ...]:
    """The tasks demonstrations are collected for: Craft's three paper tasks, Dial's one task."""
    if domain == "craft":
        return tuple(PAPER_TASKS)
    if domain == "dial":
        return (DIAL_TASK,)
    raise UnknownDomainError(f"unknown domain '{domain}', expected one of {list(DOMAINS)}")


def expert_episode(
    domain: str, seed: int, *, task: str | None = None, partial: bool = False, human: HumanLike | None = None
) -> Episode:
    """One demonstration with ground truth (``generate_episode`` of the domain).

    ``task`` defaults to the domain's first task; ``partial`` selects Craft's partial observation
    (Dial has one observation); ``human`` selects the human-like demonstrator with these parameters
    (``sim_nodes/human.py``) instead of the scripted expert.
    """
    name = task if task is not None else default_tasks(domain)[0]
    check_task(domain, name)
    if domain == "craft":
        if human is not None:
            return craft_human_episode(seed, human, task=name, full_obs=not partial)
        return craft_episode(seed, task=name, full_obs=not partial)
    return dial_episode(seed) if human is None else dial_human_episode(seed, human)


def check_task(domain: str, task: str) -> None:
    """Raise :class:`UnknownDomainError` unless ``task`` is a Craft task (``domain`` 'craft') or Dial's
    one task (any other domain)."""
    if domain == "craft":
        if task not in CRAFT_TASKS:
            raise UnknownDomainError(f"unknown Craft task '{task}'; known: {sorted(CRAFT_TASKS)}")
    elif task != DIAL_TASK:
        raise UnknownDomainError(f"unknown Dial task '{task}'; Dial has the one task '{DIAL_TASK}'")


__all__ = [
    "CRAFT_TASKS",
    "DEMONSTRATORS",
    "DIAL_TASK",
    "DOMAINS",
    "SEED_MAX",
    "CraftEnv",
    "DialEnv",
    "Domain",
    "HumanLike",
    "HumanLikeError",
    "UnknownDomainError",
    "check_task",
    "default_tasks",
    "derive_seed",
    "dial_episode_sketch",
    "expert_episode",
    "human_defaults",
    "parse_human",
]
