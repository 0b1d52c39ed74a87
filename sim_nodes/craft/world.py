"""The Craft grid world (docs/craft.md §1): kinds, recipes, tasks and the step dynamics.

Grid convention (docs/craft.md §1.3): ``grid[x, y]`` with x left→right and y **down→up** (UP is y+1).  The
agent is not written into the grid; its cell stays empty (0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final

import numpy as np

from ompn_ros.errors import OMPNError

WIDTH: Final = 10
HEIGHT: Final = 10
MAX_STEPS: Final = 64  # the authors' TimeLimit wrapper (docs/craft.md §1.5)

# --- object kinds (docs/craft.md §1.1) --------------------------------------------------------------------
KIND_NAMES: Final = (
    "empty", "boundary", "water", "stone", "toolshed", "workbench", "factory",
    "iron", "grass", "wood", "gold", "gem",
    "plank", "stick", "axe", "rope", "bed", "shears", "cloth", "bridge", "ladder",
)  # fmt: skip
N_KINDS: Final = len(KIND_NAMES)  # 21
KIND: Final = {name: i for i, name in enumerate(KIND_NAMES)}
EMPTY, BOUNDARY, WATER, STONE = 0, 1, 2, 3
TOOLSHED, WORKBENCH, FACTORY = 4, 5, 6
IRON, GRASS, WOOD, GOLD, GEM = 7, 8, 9, 10, 11
ENVIRONMENT_KINDS: Final = frozenset({BOUNDARY, WATER, STONE})
WORKSHOPS: Final = frozenset({TOOLSHED, WORKBENCH, FACTORY})
GRABBABLE: Final = frozenset(range(1, N_KINDS)) - ENVIRONMENT_KINDS - WORKSHOPS


class Action(IntEnum):
    """Env actions (docs/craft.md §1.4); the facing direction uses the same order for 0..3."""

    DOWN = 0
    UP = 1
    LEFT = 2
    RIGHT = 3
    USE = 4
    DONE = 5


N_ACTIONS: Final = 6
DIRECTION_NAMES: Final = ("down", "up", "left", "right")
DIRECTION_DELTA: Final = ((0, -1), (0, 1), (-1, 0), (1, 0))  # (dx, dy) per direction / move action


# --- recipes (docs/craft.md §1.2), in the global order the env tries them ----------------------------------
@dataclass(frozen=True)
class Recipe:
    output: int
    workshop: int
    inputs: tuple[int, ...]


RECIPES: Final = (
    Recipe(KIND["plank"], TOOLSHED, (WOOD,)),
    Recipe(KIND["axe"], TOOLSHED, (KIND["stick"], IRON)),
    Recipe(KIND["rope"], TOOLSHED, (GRASS,)),
    Recipe(KIND["stick"], WORKBENCH, (WOOD,)),
    Recipe(KIND["bed"], WORKBENCH, (KIND["plank"], GRASS)),
    Recipe(KIND["shears"], WORKBENCH, (KIND["stick"], IRON)),
    Recipe(KIND["cloth"], FACTORY, (GRASS,)),
    Recipe(KIND["bridge"], FACTORY, (WOOD, IRON)),
    Recipe(KIND["ladder"], FACTORY, (KIND["plank"], KIND["stick"])),
)


# --- tasks (docs/craft.md §1.6, envs.yaml order = env id) ---------------------------------------------------
@dataclass(frozen=True)
class Task:
    """A Craft task: the goal item and its sketch of subtask strings ('get wood', 'make at toolshed')."""

    name: str
    env_id: int
    goal: int
    sketch: tuple[str, ...]
    targets: tuple[int, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", tuple(KIND[s.split()[-1]] for s in self.sketch))


_TASK_TABLE: Final = (
    ("getwood", "wood", ("get wood",)),
    ("getgrass", "grass", ("get grass",)),
    ("getiron", "iron", ("get iron",)),
    ("makeplank", "plank", ("get wood", "make at toolshed")),
    ("makestick", "stick", ("get wood", "make at workbench")),
    ("makecloth", "cloth", ("get grass", "make at factory")),
    ("makerope", "rope", ("get grass", "make at toolshed")),
    ("makebridge", "bridge", ("get iron", "get wood", "make at factory")),
    ("makebed", "bed", ("get wood", "make at toolshed", "get grass", "make at workbench")),
    ("makeaxe", "axe", ("get wood", "make at workbench", "get iron", "make at toolshed")),
    ("makeshears", "shears", ("get wood", "make at workbench", "get iron", "make at workbench")),
    ("getgold", "gold", ("get iron", "get wood", "make at factory", "get gold")),
    ("getgem", "gem", ("get wood", "make at workbench", "get iron", "make at toolshed", "get gem")),
)
TASKS: Final = {
    name: Task(name, env_id, KIND[goal], sketch) for env_id, (name, goal, sketch) in enumerate(_TASK_TABLE)
}
PAPER_TASKS: Final = ("makebed", "makeaxe", "makeshears")


class CraftError(OMPNError, ValueError):
    """Base class of Craft input errors."""


class UnknownTaskError(CraftError):
    def __init__(self, task: object) -> None:
        super().__init__(f"unknown Craft task {task!r}; expected one of {sorted(TASKS)}")


class InvalidActionError(CraftError):
    def __init__(self, action: object) -> None:
        super().__init__(f"invalid Craft action {action!r}; expected an int in 0..{N_ACTIONS - 1}")


def get_task(name: str) -> Task:
    """The task called ``name`` or :class:`UnknownTaskError`."""
    try:
        return TASKS[name]
    except (KeyError, TypeError):
        raise UnknownTaskError(name) from None


@dataclass
class StepResult:
    reward: float
    terminated: bool  # goal item held (docs/craft.md §1.5); the time limit is the env wrapper's business
    completed_subtask: int | None  # sketch index completed by this step, if any


class CraftWorld:
    """State and dynamics of one Craft map.  ``reset(rng)`` draws a new map."""

    def __init__(self, task: str | Task) -> None:
        self.task = task if isinstance(task, Task) else get_task(task)
        self.grid = np.zeros((WIDTH, HEIGHT), dtype=np.int8)
        self.pos = (1, 1)
        self.direction = 0
        self.inventory = np.zeros(N_KINDS, dtype=np.int64)
        self.sketch_index = 0
        self.steps = 0

    # --- map generation (docs/craft.md §1.3) ---------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        """Build a new map: boundary, gold island / gem cave if the goal needs it, the 6 objects, agent."""
        grid = np.zeros((WIDTH, HEIGHT), dtype=np.int8)
        grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = BOUNDARY
        self.grid = grid
        # The agent is placed last, so no object can land on it.
        # Gold and gem are surrounded by water / stone (docs/craft.md §1.3 gives no geometry: our choice is
        # the 4-neighbourhood of a cell at least 2 cells from the wall).
        for special, cover in ((GOLD, WATER), (GEM, STONE)):
            if self.task.goal == special:
                x, y = (int(v) for v in rng.integers(2, WIDTH - 2, size=2))
                grid[x, y] = special
                for dx, dy in DIRECTION_DELTA:
                    grid[x + dx, y + dy] = cover
        for kind in (IRON, GRASS, WOOD, TOOLSHED, WORKBENCH, FACTORY):
            grid[self._random_free(rng)] = kind
        self.pos = self._random_free(rng)
        self.direction = int(rng.integers(4))
        self.inventory = np.zeros(N_KINDS, dtype=np.int64)
        self.sketch_index = 0
        self.steps = 0

    def _random_free(self, rng: np.random.Generator) -> tuple[int, int]:
        # Rejection sampling over the whole grid, like the authors' random_free.
        while True:
            x, y = (int(v) for v in rng.integers(0, WIDTH, size=2))
            if self.grid[x, y] == EMPTY:
                return x, y

    # --- dynamics (docs/craft.md §1.4-1.5) ------------------------------------------------------------------
    @property
    def front(self) -> tuple[int, int]:
        dx, dy = DIRECTION_DELTA[self.direction]
        return self.pos[0] + dx, self.pos[1] + dy

    @property
    def done(self) -> bool:
        return bool(self.inventory[self.task.goal] > 0)

    @property
    def all_subtasks_done(self) -> bool:
        return self.sketch_index >= len(self.task.sketch)

    def step(self, action: int) -> StepResult:
        """Apply one action; moves always turn the agent and move it only into empty cells."""
        if (
            isinstance(action, bool)
            or not isinstance(action, int | np.integer)
            or not 0 <= action < N_ACTIONS
        ):
            raise InvalidActionError(action)
        action = int(action)
        self.steps += 1
        if action < 4:
            self.direction = action
            fx, fy = self.front
            if self.grid[fx, fy] == EMPTY:
                self.pos = (fx, fy)
            return StepResult(0.0, self.done, None)
        if action == Action.DONE:
            return StepResult(0.0, self.done, None)
        before = self.inventory.copy()
        fx, fy = self.front
        kind = int(self.grid[fx, fy])
        if kind in GRABBABLE:
            self.inventory[kind] += 1
            self.grid[fx, fy] = EMPTY
        elif kind in WORKSHOPS:
            self._craft(kind)
        elif kind == WATER and self.inventory[KIND["bridge"]] > 0:
            self.grid[fx, fy] = EMPTY  # the bridge is not consumed (docs/craft.md §1.4)
        elif kind == STONE and self.inventory[KIND["axe"]] > 0:
            self.grid[fx, fy] = EMPTY
        completed = None
        if not self.all_subtasks_done:
            target = self.task.targets[self.sketch_index]
            if target in WORKSHOPS:
                ok = kind == target and not np.array_equal(before, self.inventory)
            else:
                ok = self.inventory[target] > before[target]
            if ok:
                completed = self.sketch_index
                self.sketch_index += 1
        return StepResult(1.0 if completed is not None else 0.0, self.done, completed)

    def _craft(self, workshop: int) -> None:
        # Every recipe of this workshop, in the global order, against the inventory as updated so far.
        inv = self.inventory
        for recipe in RECIPES:
            if recipe.workshop == workshop and all(inv[i] >= 1 for i in recipe.inputs):
                for i in recipe.inputs:
                    inv[i] -= 1
                inv[recipe.output] += 1

    # --- views ---------------------------------------------------------------------------------------
    def window(self, radius: int = 2) -> np.ndarray:
        """The (2r+1)×(2r+1) grid window around the agent, out-of-map cells 0 (the bot's partial ``img``)."""
        size = 2 * radius + 1
        out = np.zeros((size, size), dtype=np.int8)
        x, y = self.pos
        x0, x1 = max(x - radius, 0), min(x + radius + 1, WIDTH)
        y0, y1 = max(y - radius, 0), min(y + radius + 1, HEIGHT)
        out[x0 - x + radius : x1 - x + radius, y0 - y + radius : y1 - y + radius] = self.grid[x0:x1, y0:y1]
        return out

    def copy(self) -> CraftWorld:
        other = CraftWorld(self.task)
        other.grid = self.grid.copy()
        other.pos = self.pos
        other.direction = self.direction
        other.inventory = self.inventory.copy()
        other.sketch_index = self.sketch_index
        other.steps = self.steps
        return other
