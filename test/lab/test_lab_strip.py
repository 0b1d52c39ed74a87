"""Stripped copies of bags (no final observation) and what the reader makes of them."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import make_episodes

from lab.strip import StripError, strip_bags, strip_final_observations
from ompn_ros.data.cache import load_arrays
from ompn_ros.data.reader import ReaderSpec
from ompn_ros.data.recorder.bag_writer import write_episodes


def _read(bag: Path, domain: str, how: str, strict: bool = False) -> list:
    spec = replace(ReaderSpec.for_domain(domain), final_observation=how, strict=strict)
    return load_arrays(bag, spec=spec, use_cache=False).episodes()


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_strip_removes_exactly_the_final_observation(tmp_path: Path, domain: str) -> None:
    episodes = make_episodes(domain, 3, seed=4)
    write_episodes(tmp_path / "src", episodes, domain)
    stats = strip_final_observations(tmp_path / "src", tmp_path / "out")
    joints = 1 if domain == "dial" else 0
    assert stats.episodes == 3 and stats.removed == 3 * (1 + joints)

    complete = _read(tmp_path / "src", domain, "drop_last_step")
    dropped = _read(tmp_path / "out", domain, "drop_last_step")
    duplicated = _read(tmp_path / "out", domain, "duplicate")
    blanked = _read(tmp_path / "out", domain, "blank")
    guessed = _read(tmp_path / "out", domain, "extrapolate")
    for ep, full, drop, dup, blank, guess in zip(
        episodes, complete, dropped, duplicated, blanked, guessed, strict=True
    ):
        T = ep.length
        assert full.length == T
        # drop_last_step: the last recorded observation becomes row T, its action is lost
        assert drop.length == T - 1
        np.testing.assert_array_equal(drop.observations, ep.observations[:T])
        np.testing.assert_array_equal(drop.actions, ep.actions[: T - 1])
        # duplicate: every action kept, row T repeats row T-1
        assert dup.length == T
        np.testing.assert_array_equal(dup.observations[:T], ep.observations[:T])
        np.testing.assert_array_equal(dup.observations[T], ep.observations[T - 1])
        np.testing.assert_array_equal(dup.actions, ep.actions)
        assert (dup.task, dup.seed) == (ep.task, ep.seed)
        # blank: every action kept, row T all zeros (row T-1, the same recorded row, untouched)
        np.testing.assert_array_equal(blank.observations[:T], ep.observations[:T])
        assert blank.observations.shape == ep.observations.shape and not blank.observations[T].any()
        np.testing.assert_array_equal(blank.actions, ep.actions)
        # extrapolate: every action kept, row T continues the last two recorded rows linearly
        np.testing.assert_array_equal(guess.observations[:T], ep.observations[:T])
        np.testing.assert_allclose(
            guess.observations[T], 2 * ep.observations[T - 1] - ep.observations[T - 2], rtol=1e-6, atol=1e-6
        )
        np.testing.assert_array_equal(guess.actions, ep.actions)


def test_extrapolate_keeps_a_one_step_episode_a_duplicate(tmp_path: Path) -> None:
    """With a single recorded observation there is nothing to extrapolate from: row T repeats it."""
    episodes = make_episodes("dial", 2, seed=2)
    short = [replace(ep, observations=ep.observations[:2], actions=ep.actions[:1],
                     subtask=None if ep.subtask is None else ep.subtask[:1],
                     extras={k: v[:2] if k.startswith("joint_") else v for k, v in ep.extras.items()})
             for ep in episodes]
    write_episodes(tmp_path / "src", short, "dial")
    strip_final_observations(tmp_path / "src", tmp_path / "out")
    result = load_arrays(tmp_path / "out", spec=replace(ReaderSpec.for_domain("dial"),
                         final_observation="extrapolate", strict=False), use_cache=False)
    for got, ep in zip(result.episodes(), short, strict=True):
        np.testing.assert_array_equal(got.observations, ep.observations[[0, 0]])
    assert "duplicated" in result.report and "final_observation: extrapolate" not in result.report


@pytest.mark.parametrize("how", ["drop_last_step", "duplicate", "blank", "extrapolate"])
def test_stripped_bags_read_strictly(tmp_path: Path, how: str) -> None:
    """The end marker counts the recorded steps; a step dropped by ``drop_last_step`` is one of them."""
    episodes = make_episodes("craft", 2, seed=3)
    write_episodes(tmp_path / "src", episodes, "craft")
    strip_final_observations(tmp_path / "src", tmp_path / "out")
    strict = _read(tmp_path / "out", "craft", how, strict=True)
    assert [ep.length for ep in strict] == [ep.length - (how == "drop_last_step") for ep in episodes]


def test_the_default_keeps_every_recorded_action(tmp_path: Path) -> None:
    episodes = make_episodes("craft", 2, seed=5)
    write_episodes(tmp_path / "src", episodes, "craft")
    strip_final_observations(tmp_path / "src", tmp_path / "out")
    read = load_arrays(tmp_path / "out", spec=ReaderSpec.for_domain("craft"), use_cache=False).episodes()
    for got, ep in zip(read, episodes, strict=True):
        np.testing.assert_array_equal(got.actions, ep.actions)


def test_strip_bags_keeps_the_layout_of_a_directory_of_bags(tmp_path: Path) -> None:
    episodes = make_episodes("craft", 4, seed=1)
    write_episodes(tmp_path / "src" / "part_000", episodes[:2], "craft")
    write_episodes(tmp_path / "src" / "part_001", episodes[2:], "craft", first_episode_index=2)
    stats = strip_bags(tmp_path / "src", tmp_path / "out")
    assert stats.episodes == 4 and stats.removed == 4
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["part_000", "part_001"]
    assert [ep.seed for ep in _read(tmp_path / "out", "craft", "duplicate")] == [ep.seed for ep in episodes]


def test_strip_refuses_an_existing_output(tmp_path: Path) -> None:
    write_episodes(tmp_path / "src", make_episodes("craft", 1), "craft")
    (tmp_path / "out").mkdir()
    with pytest.raises(StripError, match="output exists"):
        strip_final_observations(tmp_path / "src", tmp_path / "out")
