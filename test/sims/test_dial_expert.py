"""Dial expert: seeded demonstrations succeed, carry consistent labels, actions and extras."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data.episode import Episode
from sim_nodes import derive_seed
from sim_nodes.dial import DialConfigError, generate_episode, generate_episodes
from sim_nodes.dial.env import DialEnv
from sim_nodes.dial.expert import DartNoise, DemoRollout
from sim_nodes.dial.scene import press_point

SEEDS = (0, 1, 2, 3, 4)


@pytest.fixture(scope="module")
def episodes() -> list[Episode]:
    env = DialEnv()
    return [generate_episode(s, env=env, max_retries=0) for s in SEEDS]


def test_expert_succeeds_with_valid_structure(episodes: list[Episode]) -> None:
    for ep in episodes:
        T = ep.length
        assert ep.success and ep.task == "dial" and ep.extras["attempt"] == 0
        assert 50 < T < 500
        assert ep.observations.shape == (T + 1, 39) and ep.observations.dtype == np.float32
        assert ep.actions.shape == (T, 9) and ep.actions.dtype == np.float32
        assert np.all(np.abs(ep.actions) <= 1.0)
        assert ep.sketch.shape == (4,) and not np.any(ep.sketch[1:] == ep.sketch[:-1])
        # subtask ordinals: 0, 1, 2, 3 in order, every one non-empty
        assert ep.subtask[0] == 0 and np.all(np.diff(ep.subtask) >= 0)
        assert np.bincount(ep.subtask).tolist() == [c for c in np.bincount(ep.subtask) if c > 0]
        assert set(ep.subtask.tolist()) == {0, 1, 2, 3}
        for name in ("joint_position", "joint_velocity", "joint_effort"):
            assert ep.extras[name].shape == (T + 1, 9)
        assert len(ep.extras["joint_names"]) == 9
        np.testing.assert_allclose(ep.extras["joint_position"][:, :], ep.observations[:, :9], atol=1e-5)
        assert np.all(ep.extras["joint_effort"][0] == 0.0)


def test_labels_match_presses(episodes: list[Episode]) -> None:
    """At the last step of subtask k the reference is near key sketch[k]'s press point."""
    for ep in episodes:
        bounds = ep.boundaries
        assert len(bounds) == 4
        for k, t in enumerate(bounds):
            block = ep.observations[t + 1, 9 + 3 * ep.sketch[k] : 12 + 3 * ep.sketch[k]]
            assert np.abs(block).sum() < 0.03, (ep.seed, k, block)
        first = ep.observations[0, 9 + 3 * ep.sketch[0] : 12 + 3 * ep.sketch[0]]
        assert np.abs(first).sum() > 0.05  # it did have to move


def test_recorded_actions_are_noise_free() -> None:
    """With noise the executed trajectory differs, but the recorded label is the clean expert."""
    clean = generate_episode(7, noise=0.0, max_retries=0)
    noisy = generate_episode(7, noise=0.3, max_retries=0)
    assert clean.success and noisy.success
    assert not np.allclose(clean.observations[:20], noisy.observations[:20])
    assert np.all(np.abs(noisy.actions) <= 1.0)
    # the executed torque (effort) differs from the recorded action by the held DART noise
    executed = noisy.extras["joint_effort"][1:] / np.array([30.5, 30.5, 30.5, 6.8, 6.8, 6.8, 1, 1, 1])
    assert np.abs(executed - noisy.actions).max() > 0.01
    np.testing.assert_allclose(
        clean.extras["joint_effort"][1:] / np.array([30.5, 30.5, 30.5, 6.8, 6.8, 6.8, 1, 1, 1]),
        clean.actions, atol=1e-6,
    )


def test_generate_episode_is_deterministic(episodes: list[Episode]) -> None:
    again = generate_episode(SEEDS[1], max_retries=0)
    np.testing.assert_array_equal(again.observations, episodes[1].observations)
    np.testing.assert_array_equal(again.actions, episodes[1].actions)
    np.testing.assert_array_equal(again.subtask, episodes[1].subtask)
    other = episodes[0]
    assert not np.array_equal(other.sketch, again.sketch) or other.length != again.length


def test_given_sketch_and_permutation() -> None:
    ep = generate_episode(3, sketch=[9, 0, 9, 1], permute_labels=True)
    assert ep.success and ep.sketch.tolist() == [9, 0, 9, 1]
    perm = ep.extras["permutation"]
    assert not np.array_equal(perm, np.arange(10))
    t = ep.boundaries[0]  # the press of label 9 happens at physical key perm[9]
    ref = ep.observations[t + 1, 9:12] + press_point(int(perm[0]))
    assert np.abs(ref - press_point(int(perm[9]))).sum() < 0.03


def test_generate_episodes_uses_derived_seeds() -> None:
    eps = list(generate_episodes(2, seed=5, max_retries=0))
    assert [e.seed for e in eps] == [derive_seed(5, 0), derive_seed(5, 1)]
    assert all(e.success for e in eps)


def test_bad_arguments_are_named() -> None:
    with pytest.raises(DialConfigError, match="task"):
        generate_episode(0, task="makebed")
    with pytest.raises(DialConfigError, match="noise"):
        generate_episode(0, noise=-1.0)
    with pytest.raises(DialConfigError, match="seed"):
        generate_episode(-3)
    with pytest.raises(DialConfigError, match="repeat"):
        generate_episode(0, sketch=[2, 2, 3, 4])


def test_retry_after_timeout() -> None:
    """A hopeless timeout fails every attempt; the episode says so instead of raising."""
    ep = generate_episode(0, max_retries=1, max_steps_per_subtask=2)
    assert not ep.success and ep.extras["attempt"] == 1 and ep.length == 2


def test_dart_noise_is_persistent() -> None:
    noise = DartNoise(np.random.default_rng(0), 0.3)
    while noise.amount == 0.0 or noise.persist < 2:
        noise = DartNoise(np.random.default_rng(int(noise.rng.integers(1 << 30))), 0.3)
    draws = np.array([noise.sample() for _ in range(4 * noise.persist)])
    assert np.array_equal(draws[0], draws[noise.persist - 1])
    assert not np.array_equal(draws[0], draws[noise.persist])
    assert not np.any(DartNoise(np.random.default_rng(0), 0.0).sample())
    assert DemoRollout(DialEnv(), noise=0.0).noise == 0.0
