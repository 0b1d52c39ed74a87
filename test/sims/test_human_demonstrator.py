"""The human-like demonstrator (sim_nodes/human.py): validated parameters, reproducible episodes that
differ from the expert's, exact labels, completed tasks and perturbations at the configured rates."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ompn_ros.data.episode import OBSERVATION_COPIES, observation_copies
from sim_nodes import derive_seed
from sim_nodes.craft.expert import episode_rngs, generate_episode, rollout
from sim_nodes.craft.human import HumanCraftActor, generate_human_episode
from sim_nodes.craft.world import CraftWorld
from sim_nodes.human import EVENTS_KEY, HumanLike, HumanLikeError, human_defaults, parse_human

CRAFT_TASKS = ("makebed", "makeaxe", "makeshears")


# --- parameters ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("items", "named"),
    [
        (["pause_rate=1.5"], "'pause_rate'"),
        (["sensor_noise=-0.1"], "'sensor_noise'"),
        (["pause_steps=5:2"], "'pause_steps'"),
        (["pause_steps=3"], "'pause_steps'"),
        (["speed_range=0:2"], "'speed_range'"),
        (["drop_rate=0.6", "duplicate_rate=0.6"], "'drop_rate' + 'duplicate_rate'"),
        (["overshoot_rate=abc"], "'overshoot_rate'"),
        (["tempo=2"], "'tempo=2'"),
        (["pause_rate"], "'pause_rate'"),
    ],
)
def test_a_bad_parameter_is_one_line_naming_it(items: list[str], named: str) -> None:
    with pytest.raises(HumanLikeError) as err:
        parse_human("dial", items)
    text = str(err.value)
    assert named in text and "\n" not in text


def test_parameters_parse_over_the_domain_defaults() -> None:
    human = parse_human("craft", ["pause_rate=0.2", "pause_steps=2:4"])
    assert human == dataclasses.replace(human_defaults("craft"), pause_rate=0.2, pause_steps=(2, 4))
    assert human_defaults("dial") != human_defaults("craft")
    with pytest.raises(HumanLikeError, match="domain 'mars'"):
        human_defaults("mars")


# --- Craft ---------------------------------------------------------------------------------------------
def world_labels(episode) -> tuple[list[int], CraftWorld]:
    """The world's subtask ordinal before each action, replayed from the episode's seed and actions."""
    world = CraftWorld(episode.task)
    world.reset(episode_rngs(episode.seed)[0])
    labels = []
    for action in episode.actions:
        labels.append(min(world.sketch_index, len(world.task.sketch) - 1))
        world.step(int(action))
    return labels, world


def test_craft_human_episode_is_reproducible_and_not_the_expert() -> None:
    human = human_defaults("craft")
    a = generate_human_episode(17, human, task="makeaxe")
    b = generate_human_episode(17, human, task="makeaxe")
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.extras[OBSERVATION_COPIES], b.extras[OBSERVATION_COPIES])
    expert = generate_episode(17, task="makeaxe")
    assert a.seed == expert.seed  # the same map
    assert a.length != expert.length or not np.array_equal(a.actions, expert.actions)
    assert not np.array_equal(a.observations[0], expert.observations[0])  # sensor noise


def test_craft_labels_are_the_worlds_and_wrong_moves_complete_nothing() -> None:
    """Detours in every move: still every label is the subtask the world has in progress."""
    human = dataclasses.replace(human_defaults("craft"), overshoot_rate=0.25, wrong_move_rate=0.25)
    events = 0
    for i in range(30):
        ep = generate_human_episode(derive_seed(5, i), human, task=CRAFT_TASKS[i % 3], full_obs=i % 2 == 0)
        labels, world = world_labels(ep)
        assert ep.subtask.tolist() == labels
        assert ep.success and world.all_subtasks_done
        events += ep.extras[EVENTS_KEY]["wrong_moves"] + ep.extras[EVENTS_KEY]["overshoots"]
    assert events >= 30


def test_craft_success_and_rates_match_the_parameters() -> None:
    """First attempts (no map regenerated): success share, and each perturbation's measured rate."""
    human = HumanLike(pause_rate=0.05, hesitation_rate=0.5, pause_steps=(1, 3), speed_range=(1.0, 1.0),
                      overshoot_rate=0.1, wrong_move_rate=0.1, sensor_noise=0.02, drop_rate=0.05,
                      duplicate_rate=0.05)  # fmt: skip
    totals: dict[str, int] = {}
    successes = expert_successes = runs = 0
    copies = []
    for i in range(150):
        seed, task = derive_seed(2, i), CRAFT_TASKS[i % 3]
        actor = HumanCraftActor(human)
        ep = rollout(seed, task, actor=actor)
        runs += 1
        successes += ep.success
        expert_successes += rollout(seed, task).success
        assert actor.last is not None
        for key, value in actor.last.events.items():
            totals[key] = totals.get(key, 0) + value
        if ep.success:
            copies.append(observation_copies(generate_human_episode(seed, human, task=task))[1:-1])
    assert successes / runs >= 0.95 and expert_successes / runs >= 0.95  # measured: 0.99 and 0.99
    rate = {k: totals[k] / totals[f"opportunities_{o}"] for k, o in
            (("pauses", "pause"), ("hesitations", "hesitation"), ("overshoots", "detour"),
             ("wrong_moves", "detour"))}  # fmt: skip
    assert rate["pauses"] == pytest.approx(0.05, abs=0.015)
    assert rate["hesitations"] == pytest.approx(0.5, abs=0.08)
    assert 0.05 <= rate["overshoots"] <= 0.12  # an overshoot needs two free cells ahead
    assert 0.07 <= rate["wrong_moves"] <= 0.12  # a wrong move needs a free side cell
    assert totals["pause_steps"] / (totals["pauses"] + totals["hesitations"]) == pytest.approx(2.0, abs=0.25)
    inner = np.concatenate(copies)
    print(
        f"first-attempt success human {successes / runs:.3f} expert {expert_successes / runs:.3f}; rates "
        f"{rate}; drops {np.mean(inner == 0):.4f} duplicates {np.mean(inner == 2):.4f}"
    )
    assert np.mean(inner == 0) == pytest.approx(0.05, abs=0.015)
    assert np.mean(inner == 2) == pytest.approx(0.05, abs=0.015)


# --- Dial ----------------------------------------------------------------------------------------------
dial_human = pytest.importorskip("sim_nodes.dial.human")


@pytest.fixture(scope="module")
def dial_env():
    from sim_nodes.dial.env import DialEnv

    return DialEnv()


def distance_after(ep) -> np.ndarray:
    """Per step t, the L1 distance of the finger reference after the step (row t + 1) to the press point
    of the subtask step t works on (observation columns 9.. are the offsets to every label's press point)."""
    offsets = ep.observations[1:, 9:].reshape(ep.length, 10, 3)
    keys = ep.sketch[ep.subtask]
    return np.abs(offsets[np.arange(ep.length), keys]).sum(axis=1)


def test_dial_detours_in_every_subtask_keep_labels_exact(dial_env) -> None:
    """Sensor noise off, a detour in every subtask: a label advances exactly when the env saw the press
    (no earlier pose was within the press tolerance, the pose after the step is at the key)."""
    from sim_nodes.dial.env import PRESS_TOLERANCE

    human = dataclasses.replace(human_defaults("dial"), overshoot_rate=0.5, wrong_move_rate=0.5,
                                sensor_noise=0.0)  # fmt: skip
    for seed in (3, 4):
        ep = dial_human.generate_human_episode(seed, human, max_retries=0, env=dial_env)
        assert ep.success
        events = ep.extras[EVENTS_KEY]
        assert events["overshoots"] + events["wrong_moves"] == 4
        labels = ep.subtask
        assert labels[0] == 0 and np.all(np.diff(labels) >= 0) and np.all(np.diff(labels) <= 1)
        distance = distance_after(ep)
        for t in [*np.flatnonzero(np.diff(labels) == 1).tolist(), ep.length - 1]:
            start = int(np.searchsorted(labels, labels[t]))  # first step of that subtask
            assert np.all(distance[start:t] >= PRESS_TOLERANCE - 1e-5), (seed, t)
            assert distance[t] < 3 * PRESS_TOLERANCE, (seed, t)


def test_dial_human_episode_is_reproducible_and_not_the_expert(dial_env) -> None:
    from sim_nodes.dial.expert import generate_episode as dial_expert

    human = human_defaults("dial")
    a = dial_human.generate_human_episode(11, human, max_retries=0, env=dial_env)
    b = dial_human.generate_human_episode(11, human, max_retries=0, env=dial_env)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.extras["joint_position"], b.extras["joint_position"])
    assert a.extras[EVENTS_KEY] == b.extras[EVENTS_KEY]
    expert = dial_expert(11, max_retries=0, env=dial_env)
    assert a.success and expert.success
    assert a.length != expert.length
    np.testing.assert_array_equal(a.sketch, expert.sketch)
    assert a.extras[EVENTS_KEY]["pause_steps"] > 0


def test_dial_rates_match_the_parameters(dial_env) -> None:
    human = dataclasses.replace(human_defaults("dial"), pause_rate=0.05, pause_steps=(1, 1), drop_rate=0.05,
                                duplicate_rate=0.05)  # fmt: skip
    totals: dict[str, int] = {}
    copies = []
    for seed in range(4):
        ep = dial_human.generate_human_episode(seed, human, max_retries=0, env=dial_env)
        assert ep.success
        for key, value in ep.extras[EVENTS_KEY].items():
            totals[key] = totals.get(key, 0) + value
        copies.append(observation_copies(ep)[1:-1])
    assert totals["opportunities_pause"] > 700
    assert totals["pauses"] / totals["opportunities_pause"] == pytest.approx(0.05, abs=0.02)
    assert totals["opportunities_detour"] == 16 and totals["overshoots"] + totals["wrong_moves"] > 0
    inner = np.concatenate(copies)
    assert np.mean(inner == 0) == pytest.approx(0.05, abs=0.02)
    assert np.mean(inner == 2) == pytest.approx(0.05, abs=0.02)
