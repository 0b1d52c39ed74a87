"""Gymnasium wrapper of Craft: registration, reset/step contract, time limit, renderings."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim_nodes.craft  # noqa: F401  (registers ompn_ros/Craft-v0)
from sim_nodes import registry
from sim_nodes.craft import CraftEnv, generate_episode
from sim_nodes.craft.world import UnknownTaskError


def test_registered_env_replays_expert_episode():
    env = gym.make("ompn_ros/Craft-v0", task="makeshears", full_obs=False)
    ep = generate_episode(5, task="makeshears", full_obs=False)
    obs, info = env.reset(seed=ep.seed)
    assert obs.shape == (1075,) and obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert np.array_equal(obs, ep.observations[0])
    rewards = []
    for t, a in enumerate(ep.actions):
        obs, r, terminated, truncated, info = env.step(int(a))
        rewards.append(r)
        assert np.array_equal(obs, ep.observations[t + 1])
        assert info["step_subtask"] == ep.subtask[t]
    assert terminated and not truncated and info["success"]
    assert sum(rewards) == 4.0
    assert np.flatnonzero(rewards).tolist() == np.flatnonzero(ep.actions == 4).tolist()


def test_time_limit_truncates_at_64_steps():
    env = CraftEnv("makebed")
    env.reset(seed=0)
    for t in range(64):
        _, _, terminated, truncated, _ = env.step(5)  # DONE is a no-op
        assert not terminated
        assert truncated == (t == 63)


def test_reset_without_seed_continues_the_stream():
    env = CraftEnv("makeaxe")
    first, _ = env.reset(seed=3)
    second, _ = env.reset()
    again, _ = CraftEnv("makeaxe").reset(seed=3)
    assert np.array_equal(first, again) and not np.array_equal(first, second)


def test_renderings():
    env = CraftEnv("makebed", render_mode="ansi")
    env.reset(seed=1)
    text = env.render()
    rows = text.splitlines()
    assert rows[0] == " ".join(["#"] * 10) and len(rows) == 12
    assert sum(r.count(c) for r in rows[:10] for c in "v^<>") == 1
    assert "task=makebed" in text
    env = CraftEnv("makebed", render_mode="rgb_array")
    env.reset(seed=1)
    img = env.render()
    assert img.dtype == np.uint8 and img.shape == (240, 240, 3)
    assert len(np.unique(img.reshape(-1, 3), axis=0)) >= 8  # walls, floor, 6 objects, agent


def test_bad_arguments():
    with pytest.raises(UnknownTaskError):
        CraftEnv("makepizza")
    with pytest.raises(ValueError, match="render_mode"):
        CraftEnv(render_mode="human")


def test_registry_generates_by_domain_name_and_names_bad_input() -> None:
    assert registry.default_tasks("craft") == ("makebed", "makeaxe", "makeshears")
    via_registry = registry.expert_episode("craft", 11, task="makeaxe", partial=True)
    direct = generate_episode(11, task="makeaxe", full_obs=False)
    assert via_registry.task == "makeaxe"
    np.testing.assert_array_equal(via_registry.observations, direct.observations)
    with pytest.raises(registry.UnknownDomainError, match="unknown domain 'grid'"):
        registry.default_tasks("grid")
    with pytest.raises(registry.UnknownDomainError, match="unknown Craft task 'fly'"):
        registry.expert_episode("craft", 0, task="fly")
    with pytest.raises(registry.UnknownDomainError, match="Dial task 'makebed'"):
        registry.expert_episode("dial", 0, task="makebed")
