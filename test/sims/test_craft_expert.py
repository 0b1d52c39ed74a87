"""Expert bot: the quirky BFS, seeded determinism, and demo statistics (docs/craft.md §2)."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data.episode import Episode
from sim_nodes import derive_seed
from sim_nodes.craft.expert import (
    EpisodeGenerationError,
    ExpertBot,
    PlanningError,
    bot_observation,
    find_path,
    generate_episode,
    generate_episodes,
    rollout,
)
from sim_nodes.craft.world import BOUNDARY, IRON, WOOD, Action, CraftWorld


def open_belief() -> np.ndarray:
    b = np.zeros((10, 10), dtype=np.int8)
    b[0, :] = b[-1, :] = b[:, 0] = b[:, -1] = BOUNDARY
    return b


def test_bfs_queue_discipline_is_not_fifo():
    b = open_belief()
    b[5, 5] = WOOD
    # insert(-1) keeps the first-enqueued neighbour (6, 5) last forever: a detour of +2 (hand-traced)
    assert find_path(b, (7, 5), (5, 5)) == [(7, 5), (7, 4), (6, 4), (5, 4), (5, 5)]
    assert find_path(b, (5, 4), (5, 5)) == [(5, 4), (5, 5)]
    b[4:7, 4:7] = IRON
    b[5, 5] = WOOD
    assert find_path(b, (2, 2), (5, 5)) is None  # walled in: only the target itself is passable


def test_full_obs_unreachable_target_raises_planning_error():
    w = CraftWorld("makebed")
    w.reset(np.random.default_rng(0))
    ((x, y),) = np.argwhere(w.grid == WOOD)
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        if w.grid[x + dx, y + dy] == 0:
            w.grid[x + dx, y + dy] = 3  # stone
    if w.pos in {(x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)}:
        pytest.skip("agent spawned next to the wood")
    bot = ExpertBot("makebed", full_obs=True)
    with pytest.raises(PlanningError):
        for _ in range(5):
            w.step(bot.act(bot_observation(w, True)))


def check_episode(ep: Episode, task: str) -> None:
    assert ep.success and ep.task == task
    assert ep.observations.dtype == np.float32 and ep.observations.shape == (ep.length + 1, 1075)
    assert ep.actions.dtype == np.int64 and ep.subtask.dtype == np.int64
    uses = np.flatnonzero(ep.actions == Action.USE)
    assert len(uses) == 4 and uses[-1] == ep.length - 1  # 4 USEs, the last action completes the goal
    assert np.array_equal(ep.boundaries, uses)  # each USE is the last step of its subtask
    assert np.all(np.diff(ep.subtask) >= 0) and ep.subtask[0] == 0 and ep.subtask[-1] == 3
    assert not np.any(ep.actions == Action.DONE)


@pytest.mark.parametrize("task", ["makebed", "makeaxe", "makeshears"])
def test_full_obs_bot_statistics(task):
    eps = list(generate_episodes(100, task=task, full_obs=True, seed=123))
    for ep in eps:
        check_episode(ep, task)
    mean = np.mean([ep.length for ep in eps])
    assert 21.0 <= mean <= 26.5, mean  # docs/craft.md §2.5: 23.5-23.8 on 500 episodes (SE of 100 ≈ 0.7)
    assert np.mean([ep.extras["attempts"] for ep in eps]) < 1.05  # ~0.2 % rejected


@pytest.mark.parametrize("task", ["makebed", "makeaxe", "makeshears"])
def test_partial_obs_bot_statistics(task):
    eps = list(generate_episodes(100, task=task, full_obs=False, seed=7))
    for ep in eps:
        check_episode(ep, task)
        assert ep.observations[:, 525:1050].sum() == 0
    mean = np.mean([ep.length for ep in eps])
    assert 31.0 <= mean <= 41.0, mean  # docs/craft.md §2.5: 34.8-36.5
    first = np.mean([np.sum(ep.subtask == 0) for ep in eps])
    assert first > 9.0  # the first subtask carries the exploration (spec: 12.8-13.8)


@pytest.mark.parametrize("full_obs", [True, False])
def test_determinism_under_a_seed(full_obs):
    a = generate_episode(42, task="makeaxe", full_obs=full_obs)
    b = generate_episode(42, task="makeaxe", full_obs=full_obs)
    assert np.array_equal(a.observations, b.observations) and np.array_equal(a.actions, b.actions)
    again = rollout(a.seed, "makeaxe", full_obs=full_obs)  # the recorded seed reproduces the episode
    assert np.array_equal(again.actions, a.actions)
    others = [generate_episode(s, task="makeaxe", full_obs=full_obs) for s in (43, 44)]
    assert any(not np.array_equal(o.observations[0], a.observations[0]) for o in others)


def test_retries_use_derived_seeds_and_report_them():
    # find a seed whose first attempt fails, then check the episode reports the derived seed
    for seed in range(2000):
        try:
            if rollout(seed, "makebed", full_obs=False).success:
                continue
        except PlanningError:
            pass
        ep = generate_episode(seed, task="makebed", full_obs=False)
        assert ep.seed != seed and ep.extras["attempts"] >= 2
        assert ep.seed in {derive_seed(seed, k, stream=1) for k in range(1, 101)}
        break
    else:
        pytest.fail("no failing partial-obs seed found")


def test_generation_error_when_no_retries_allowed():
    for seed in range(2000):
        try:
            if not rollout(seed, "makebed", full_obs=False).success:
                break
        except PlanningError:
            break
    with pytest.raises(EpisodeGenerationError, match=f"seed {seed}"):
        generate_episode(seed, task="makebed", full_obs=False, max_retries=0)
