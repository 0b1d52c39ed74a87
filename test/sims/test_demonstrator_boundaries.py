"""Pauses where people make them (``boundary_rate``, sim_nodes/human.py): at a subtask change the
human-like demonstrator of either sim pauses, then corrects itself, at the documented rate; off by
default, where the episodes stay those of before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_nodes.craft.human import generate_human_episode as craft_human
from sim_nodes.human import BOUNDARY_MODE, EVENTS_KEY, HumanLike, human_defaults, parse_human

TASKS = ("makebed", "makeaxe", "makeshears")


def _totals(eps: list) -> dict[str, int]:
    out: dict[str, int] = {}
    for ep in eps:
        for key, value in ep.extras[EVENTS_KEY].items():
            out[key] = out.get(key, 0) + value
    return out


def test_off_by_default_and_named_in_the_settings_only_when_on() -> None:
    base = human_defaults("craft")
    assert base.boundary_rate == 0.0 and "boundary_rate" not in base.as_dict()
    assert parse_human("craft", BOUNDARY_MODE).as_dict()["boundary_rate"] == 0.5
    ep = craft_human(5, base, task="makeaxe")
    assert ep.extras[EVENTS_KEY]["sidetracks"] == ep.extras[EVENTS_KEY]["opportunities_sidetrack"] == 0


def test_craft_sidetracks_follow_subtask_changes_at_the_rate() -> None:
    human = dataclasses.replace(parse_human("craft", BOUNDARY_MODE), sensor_noise=0.0, hesitation_rate=0.0,
                                overshoot_rate=0.0, wrong_move_rate=0.0, drop_rate=0.0, duplicate_rate=0.0)
    eps = [craft_human(seed, human, task=TASKS[seed % 3]) for seed in range(90)]
    totals = _totals(eps)
    labels = [np.asarray(ep.subtask) for ep in eps]
    count = sum(int(np.sum(np.diff(lab) != 0)) for lab in labels)  # a change the bot meets with a USE
    assert 0.95 * count <= totals["opportunities_sidetrack"] <= count  # waits for its next move
    assert totals["sidetracks"] / totals["opportunities_sidetrack"] == pytest.approx(0.5, abs=0.1)
    assert totals["pauses"] == totals["sidetracks"]  # no pause anywhere else (pause_rate=0)
    assert totals["overshoots"] + totals["wrong_moves"] >= 0.8 * totals["sidetracks"]  # each corrected
    near = far = 0
    for ep, lab in zip(eps, labels, strict=True):  # each pause step lies within 4 steps after a change
        repeat = np.flatnonzero(np.abs(np.diff(ep.observations[: ep.length + 1], axis=0)).max(axis=1) == 0)
        changes = np.flatnonzero(np.diff(lab) != 0) + 1
        for t in repeat:
            after = t - changes[changes <= t]
            near += int(after.size > 0 and after.min() <= human.pause_steps[1] + 1)
            far += int(not (after.size > 0 and after.min() <= human.pause_steps[1] + 1))
    assert near > 30 and far <= 0.1 * near


def test_dial_sidetracks_pause_and_force_the_subtasks_detour() -> None:
    from sim_nodes.dial.env import DialEnv
    from sim_nodes.dial.human import generate_human_episode as dial_human

    human = dataclasses.replace(HumanLike(), pause_rate=0.0, hesitation_rate=0.0, boundary_rate=1.0,
                                overshoot_rate=0.0, wrong_move_rate=0.0, sensor_noise=0.0)
    env = DialEnv()
    eps = [dial_human(seed, human, max_retries=0, env=env) for seed in (1, 2)]
    totals = _totals(eps)
    assert totals["opportunities_sidetrack"] == totals["sidetracks"] == 6  # 3 changes in each 4-key episode
    assert totals["pauses"] == 6 and totals["overshoots"] + totals["wrong_moves"] == 6
    assert all(ep.success for ep in eps)
    assert all(np.all(np.diff(np.asarray(ep.subtask)) >= 0) for ep in eps)
