"""Craft world dynamics: recipes (incl. multi-craft), movement, facing, USE, reward, tasks."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.craft.world import (
    BOUNDARY,
    FACTORY,
    GRASS,
    IRON,
    KIND,
    N_KINDS,
    STONE,
    TASKS,
    TOOLSHED,
    WATER,
    WOOD,
    WORKBENCH,
    Action,
    CraftWorld,
    InvalidActionError,
    UnknownTaskError,
    get_task,
)


def empty_world(task: str = "makebed", pos=(4, 4), direction=0) -> CraftWorld:
    w = CraftWorld(task)
    w.grid = np.zeros((10, 10), dtype=np.int8)
    w.grid[0, :] = w.grid[-1, :] = w.grid[:, 0] = w.grid[:, -1] = BOUNDARY
    w.pos, w.direction = pos, direction
    w.inventory = np.zeros(N_KINDS, dtype=np.int64)
    return w


def test_kind_ids_match_spec():
    assert N_KINDS == 21
    names = "empty boundary water stone toolshed workbench factory iron grass wood gold gem plank stick axe"
    names += " rope bed shears cloth bridge ladder"
    expected = {name: i for i, name in enumerate(names.split())}
    assert expected == KIND


def test_multi_craft_stick_then_shears_on_one_use():
    w = empty_world(direction=int(Action.RIGHT))
    w.grid[5, 4] = WORKBENCH
    w.inventory[WOOD] = 1
    w.inventory[IRON] = 1
    w.step(Action.USE)
    assert w.inventory[KIND["shears"]] == 1
    assert w.inventory[KIND["stick"]] == 0 and w.inventory[WOOD] == 0 and w.inventory[IRON] == 0
    assert w.grid[5, 4] == WORKBENCH  # workshops stay


def test_toolshed_recipes_in_global_order():
    w = empty_world(direction=int(Action.UP))
    w.grid[4, 5] = TOOLSHED
    w.inventory[[WOOD, IRON, GRASS]] = 1
    w.step(Action.USE)
    # plank <- wood, axe needs a stick (none: the stick recipe is at the workbench), rope <- grass
    assert w.inventory[KIND["plank"]] == 1 and w.inventory[KIND["rope"]] == 1
    assert w.inventory[KIND["axe"]] == 0 and w.inventory[IRON] == 1


def test_factory_bridge_and_ladder():
    w = empty_world(direction=int(Action.DOWN))
    w.grid[4, 3] = FACTORY
    w.inventory[[WOOD, IRON, KIND["plank"], KIND["stick"]]] = 1
    w.step(Action.USE)
    assert w.inventory[KIND["bridge"]] == 1 and w.inventory[KIND["ladder"]] == 1
    assert w.inventory.sum() == 2


def test_use_grabs_and_clears_cell_and_ignores_empty_and_boundary():
    w = empty_world(pos=(1, 1), direction=int(Action.LEFT))
    before = w.inventory.copy()
    w.step(Action.USE)  # boundary
    assert np.array_equal(w.inventory, before) and w.grid[0, 1] == BOUNDARY
    w.grid[1, 2] = WOOD
    w.step(Action.UP)  # turn only: wood blocks
    assert w.pos == (1, 1) and w.direction == Action.UP
    w.step(Action.USE)
    assert w.inventory[WOOD] == 1 and w.grid[1, 2] == 0


def test_water_needs_bridge_which_is_kept_and_stone_needs_axe():
    w = empty_world(direction=int(Action.RIGHT))
    w.grid[5, 4] = WATER
    w.step(Action.USE)
    assert w.grid[5, 4] == WATER
    w.inventory[KIND["bridge"]] = 1
    w.step(Action.USE)
    assert w.grid[5, 4] == 0 and w.inventory[KIND["bridge"]] == 1
    w.grid[3, 4] = STONE
    w.step(Action.LEFT)
    w.step(Action.USE)
    assert w.grid[3, 4] == STONE
    w.inventory[KIND["axe"]] = 1
    w.step(Action.USE)
    assert w.grid[3, 4] == 0


@pytest.mark.parametrize(
    ("action", "delta"),
    [(Action.DOWN, (0, -1)), (Action.UP, (0, 1)), (Action.LEFT, (-1, 0)), (Action.RIGHT, (1, 0))],
)
def test_moves_set_facing_and_move_into_empty(action, delta):
    w = empty_world(pos=(4, 4), direction=int(Action.UP) if action != Action.UP else int(Action.DOWN))
    w.step(action)
    assert w.direction == int(action)
    assert w.pos == (4 + delta[0], 4 + delta[1])


def test_move_against_wall_and_object_only_turns():
    w = empty_world(pos=(1, 8), direction=int(Action.DOWN))
    w.step(Action.UP)
    assert w.pos == (1, 8) and w.direction == Action.UP
    w.step(Action.LEFT)
    assert w.pos == (1, 8) and w.direction == Action.LEFT
    w.grid[2, 8] = IRON
    w.step(Action.RIGHT)
    assert w.pos == (1, 8) and w.direction == Action.RIGHT and w.front == (2, 8)


def test_done_is_a_noop_and_invalid_actions_raise():
    w = empty_world()
    state = (w.pos, w.direction, w.inventory.copy(), w.grid.copy())
    r = w.step(Action.DONE)
    assert r.reward == 0 and not r.terminated
    assert state[0] == w.pos and state[1] == w.direction and np.array_equal(state[3], w.grid)
    for bad in (6, -1, 2.5, "up", True):
        with pytest.raises(InvalidActionError):
            w.step(bad)  # type: ignore[arg-type]


def test_dense_reward_follows_sketch_order_and_goal_terminates():
    w = empty_world("makebed", pos=(4, 4), direction=int(Action.RIGHT))
    w.grid[5, 4] = GRASS
    assert w.step(Action.USE).reward == 0.0  # grass out of order: no reward, no advance
    assert w.sketch_index == 0
    w.grid[5, 4] = WOOD
    r = w.step(Action.USE)
    assert r.reward == 1.0 and r.completed_subtask == 0 and w.sketch_index == 1
    w.grid[5, 4] = TOOLSHED
    r = w.step(Action.USE)  # wood -> plank and grass -> rope: any inventory change counts
    assert r.reward == 1.0 and w.sketch_index == 2
    w.grid[5, 4] = GRASS
    assert w.step(Action.USE).reward == 1.0
    w.grid[5, 4] = WORKBENCH
    r = w.step(Action.USE)
    assert r.reward == 1.0 and r.terminated and w.all_subtasks_done and w.inventory[KIND["bed"]] == 1


def test_workshop_use_without_change_gives_no_reward():
    w = empty_world("makeaxe", direction=int(Action.RIGHT))
    w.sketch_index = 1  # make at workbench
    w.grid[5, 4] = WORKBENCH
    assert w.step(Action.USE).reward == 0.0 and w.sketch_index == 1


def test_tasks_and_sketches():
    assert len(TASKS) == 13
    assert [t.env_id for t in TASKS.values()] == list(range(13))
    assert get_task("makebed").sketch == ("get wood", "make at toolshed", "get grass", "make at workbench")
    assert get_task("makeaxe").sketch == ("get wood", "make at workbench", "get iron", "make at toolshed")
    assert get_task("makeshears").sketch == ("get wood", "make at workbench", "get iron", "make at workbench")
    assert get_task("makeshears").goal == KIND["shears"]
    with pytest.raises(UnknownTaskError, match="nonsense"):
        get_task("nonsense")


def test_map_generation_places_six_objects_and_agent_on_free_cell():
    for seed in range(50):
        w = CraftWorld("makebed")
        w.reset(np.random.default_rng(seed))
        interior = w.grid[1:-1, 1:-1]
        assert sorted(interior[interior != 0].tolist()) == [4, 5, 6, 7, 8, 9]
        assert (w.grid[0, :] == BOUNDARY).all() and (w.grid[:, -1] == BOUNDARY).all()
        assert w.grid[w.pos] == 0 and 0 <= w.direction < 4
        assert w.inventory.sum() == 0 and w.sketch_index == 0


def test_gold_island_and_gem_cave():
    for task, special, cover in (("getgold", KIND["gold"], WATER), ("getgem", KIND["gem"], STONE)):
        w = CraftWorld(task)
        w.reset(np.random.default_rng(1))
        ((x, y),) = np.argwhere(w.grid == special)
        assert all(w.grid[x + dx, y + dy] == cover for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)))
