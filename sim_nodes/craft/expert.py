"""The authors' expert bot (docs/craft.md §2) and the demonstration generator.

Full observation: one BFS plan per subtask with the authors' quirky queue (``list.insert(-1, node)``),
which yields ~11% non-shortest paths and the published episode-length statistics.  Partial observation:
a belief map plus left-to-right, down-to-top exploration with a *seeded* random choice (the authors'
``random.choice`` was unseeded).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ompn_ros.data.episode import Episode
from sim_nodes import derive_seed
from sim_nodes.craft.features import N_FEATURES, world_features
from sim_nodes.craft.sketch import sketch_ids
from sim_nodes.craft.world import (
    DIRECTION_DELTA,
    GEM,
    GOLD,
    HEIGHT,
    MAX_STEPS,
    STONE,
    WATER,
    WIDTH,
    WORKSHOPS,
    Action,
    CraftWorld,
    Task,
    get_task,
)

UNKNOWN = -1
Cell = tuple[int, int]
_RETRY_STREAM = 1


class PlanningError(RuntimeError):
    """The expert cannot reach its target (walled in, or nothing left to explore)."""


class EpisodeGenerationError(RuntimeError):
    """No successful episode within the allowed retries."""


@dataclass
class BotObservation:
    """What the bot sees: ``img`` is the full grid or the 5×5 window (out-of-map cells 0)."""

    img: np.ndarray
    pos: Cell
    direction: int
    inventory: np.ndarray


def bot_observation(world: CraftWorld, full_obs: bool) -> BotObservation:
    img = world.grid.copy() if full_obs else world.window(2)
    return BotObservation(img, world.pos, world.direction, world.inventory.copy())


def _move_toward(src: Cell, dst: Cell) -> int:
    dx, dy = dst[0] - src[0], dst[1] - src[1]
    return int(DIRECTION_DELTA.index((dx, dy)))


def find_path(
    belief: np.ndarray, start: Cell, target: Cell, passable: frozenset[int] = frozenset()
) -> list[Cell] | None:
    """The authors' BFS (docs/craft.md §2.2): pop the front, enqueue with ``insert(-1, node)``.

    Neighbour order left, down, right, up.  Passable: empty cells (0), kinds in ``passable``, and the
    target itself.  Returns the cells from ``start`` to ``target`` inclusive, or ``None``.
    """
    parent: dict[Cell, Cell | None] = {start: None}
    queue: list[Cell] = [start]
    width, height = belief.shape
    while queue:
        node = queue.pop(0)
        if node == target:
            path = [node]
            while (prev := parent[path[-1]]) is not None:
                path.append(prev)
            return path[::-1]
        x, y = node
        for nxt in ((x - 1, y), (x, y - 1), (x + 1, y), (x, y + 1)):
            if nxt in parent or not (0 <= nxt[0] < width and 0 <= nxt[1] < height):
                continue
            value = belief[nxt]
            if nxt == target or value == 0 or value in passable:
                parent[nxt] = node
                queue.insert(-1, nxt)
    return None


class _Subgoal:
    def satisfied(self, bot: ExpertBot, prev_action: int | None) -> bool:
        raise NotImplementedError

    def act(self, bot: ExpertBot) -> int | _Subgoal:
        raise NotImplementedError


class GoTo(_Subgoal):
    """Reach and USE ``target`` (a grabbable item or a workshop)."""

    def __init__(self, target: int) -> None:
        self.target = target
        self.candidates: list[Cell] = []
        self.plan: list[Cell] | None = None
        self.acted_inventory: np.ndarray | None = None
        self.passable = frozenset({WATER, STONE}) if target in (GOLD, GEM) else frozenset()

    def satisfied(self, bot: ExpertBot, prev_action: int | None) -> bool:
        if self.target in WORKSHOPS:
            return (
                prev_action == Action.USE
                and bot.belief[bot.front] == self.target
                and self.acted_inventory is not None
                and not np.array_equal(self.acted_inventory, bot.inventory)
            )
        return bool(bot.inventory[self.target] > 0)

    def _plan(self, bot: ExpertBot) -> list[Cell] | None:
        if not self.candidates:
            self.candidates = [(int(x), int(y)) for x, y in np.argwhere(bot.belief == self.target)]
        best: list[Cell] | None = None
        for cell in self.candidates:
            path = find_path(bot.belief, bot.pos, cell, self.passable)
            if path is not None and (best is None or len(path) < len(best)):
                best = path
        return best

    def act(self, bot: ExpertBot) -> int | _Subgoal:
        if self.plan is None or self.plan[0] != bot.pos:
            self.plan = self._plan(bot)
        if self.plan is None:
            return Explore(self.target)
        self.acted_inventory = bot.inventory.copy()
        front = bot.front
        if front == self.plan[-1]:
            return int(Action.USE)
        nxt = self.plan[1]
        move = _move_toward(bot.pos, nxt)
        value = bot.belief[nxt]
        if value == 0:
            self.plan.pop(0)
            return move
        if value in (WATER, STONE) or nxt == self.plan[-1]:
            return int(Action.USE) if front == nxt else move  # adjacent: turn first, USE next step
        self.plan = None  # stale plan through a non-empty cell; replan next step
        return move


class Explore(_Subgoal):
    """Walk toward the first unknown cell in (x, then y) order until ``target`` is seen.

    docs/craft.md §2.3.
    """

    _ORDER = (Action.RIGHT, Action.LEFT, Action.UP, Action.DOWN)
    _FALLBACK = (Action.UP, Action.DOWN, Action.LEFT, Action.RIGHT)

    def __init__(self, target: int) -> None:
        self.target = target

    def satisfied(self, bot: ExpertBot, prev_action: int | None) -> bool:
        return bool(np.any(bot.belief == self.target))

    def act(self, bot: ExpertBot) -> int | _Subgoal:
        unknown = np.argwhere(bot.belief == UNKNOWN)  # row-major: lexicographic (x, y)
        if len(unknown) == 0:
            raise PlanningError(f"target {self.target} is unreachable")
        ux, uy = int(unknown[0][0]), int(unknown[0][1])
        x, y = bot.pos
        dist = abs(x - ux) + abs(y - uy)
        width, height = bot.belief.shape
        candidates = []
        for action in self._ORDER:
            dx, dy = DIRECTION_DELTA[action]
            nx, ny = x + dx, y + dy
            if 0 <= nx < width and 0 <= ny < height and bot.belief[nx, ny] == 0:
                if abs(nx - ux) + abs(ny - uy) < dist:
                    candidates.append(action)
        pool = candidates or self._FALLBACK
        return int(pool[int(bot.rng.integers(len(pool)))])


class ExpertBot:
    """Stack of subgoals, one GoTo per sketch entry (docs/craft.md §2.1); Explore pushed on demand.

    The authors keep one belief per GoTo, all updated every step from the same observations, hence
    identical: one shared belief is equivalent.
    """

    def __init__(
        self, task: str | Task, *, full_obs: bool = True, rng: np.random.Generator | None = None
    ) -> None:
        self.task = task if isinstance(task, Task) else get_task(task)
        self.full_obs = full_obs
        self.rng = rng if rng is not None else np.random.default_rng()
        self.reset()

    def reset(self) -> None:
        self.stack: list[_Subgoal] = [GoTo(t) for t in self.task.targets]
        self.belief = np.full((WIDTH, HEIGHT), UNKNOWN, dtype=np.int8)
        self.prev_action: int | None = None
        self.pos: Cell = (0, 0)
        self.direction = 0
        self.inventory = np.zeros(0)

    @property
    def front(self) -> Cell:
        dx, dy = DIRECTION_DELTA[self.direction]
        return self.pos[0] + dx, self.pos[1] + dy

    def update(self, obs: BotObservation) -> None:
        self.pos, self.direction, self.inventory = obs.pos, obs.direction, obs.inventory
        if self.full_obs:
            self.belief[:] = obs.img
            return
        x, y = obs.pos
        r = obs.img.shape[0] // 2
        x0, x1 = max(x - r, 0), min(x + r + 1, WIDTH)
        y0, y1 = max(y - r, 0), min(y + r + 1, HEIGHT)
        self.belief[x0:x1, y0:y1] = obs.img[x0 - x + r : x1 - x + r, y0 - y + r : y1 - y + r]

    def act(self, obs: BotObservation) -> int:
        """The next action (docs/craft.md §2.1 steps 1-4); raises :class:`PlanningError`."""
        self.update(obs)
        while self.stack and self.stack[0].satisfied(self, self.prev_action):
            self.stack.pop(0)
        if not self.stack:
            self.prev_action = int(Action.DONE)
            return self.prev_action
        while True:
            result = self.stack[0].act(self)
            if isinstance(result, _Subgoal):
                self.stack.insert(0, result)
                continue
            self.prev_action = int(result)
            return self.prev_action


# --- demonstrations -----------------------------------------------------------------------------------
def episode_rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """(map RNG, bot RNG) of an episode seed; the map RNG is what ``CraftEnv.reset(seed=seed)`` uses."""
    return np.random.default_rng(seed), np.random.default_rng([seed, 1])


Actor = Callable[[CraftWorld, ExpertBot, int], Callable[[], int]]
"""Builds an episode's demonstrator from (world, expert bot, episode seed): a call returns the next action."""


def expert_actor(world: CraftWorld, bot: ExpertBot, seed: int) -> Callable[[], int]:
    """The scripted expert: the bot's action on what it observes."""
    return lambda: bot.act(bot_observation(world, bot.full_obs))


def rollout(
    seed: int, task: str | Task = "makebed", *, full_obs: bool = True, actor: Actor = expert_actor
) -> Episode:
    """One episode from ``seed`` (may fail: ``success=False``; raises :class:`PlanningError`).

    ``actor`` chooses the actions (default: the expert; :mod:`sim_nodes.craft.human`: human-like).
    """
    spec = task if isinstance(task, Task) else get_task(task)
    map_rng, bot_rng = episode_rngs(seed)
    world = CraftWorld(spec)
    world.reset(map_rng)
    bot = ExpertBot(spec, full_obs=full_obs, rng=bot_rng)
    act = actor(world, bot, seed)
    obs = np.empty((MAX_STEPS + 1, N_FEATURES), dtype=np.float32)
    actions = np.empty(MAX_STEPS, dtype=np.int64)
    subtask = np.empty(MAX_STEPS, dtype=np.int64)
    t = 0
    world_features(world, full_obs=full_obs, out=obs[0])
    while t < MAX_STEPS and not world.done:
        action = act()
        subtask[t] = min(world.sketch_index, len(spec.sketch) - 1)
        actions[t] = action
        world.step(action)
        t += 1
        world_features(world, full_obs=full_obs, out=obs[t])
    return Episode(
        observations=obs[: t + 1].copy(),
        actions=actions[:t].copy(),
        subtask=subtask[:t].copy(),
        sketch=sketch_ids(spec),
        task=spec.name,
        seed=int(seed),
        success=world.all_subtasks_done,
    )


def generate_episode(
    seed: int, *, task: str = "makebed", full_obs: bool = True, max_retries: int = 100,
    actor: Actor = expert_actor,
) -> Episode:
    """A *successful* expert episode (the authors' filter, docs/craft.md §2.4).

    Attempt 0 uses ``seed``; attempt k ≥ 1 uses ``derive_seed(seed, k, stream=1)``.  The returned
    ``Episode.seed`` is the seed actually used, so ``rollout(ep.seed, ...)`` reproduces it.
    """
    spec = get_task(task)
    failures: list[str] = []
    for attempt in range(max_retries + 1):
        s = seed if attempt == 0 else derive_seed(seed, attempt, stream=_RETRY_STREAM)
        try:
            episode = rollout(s, spec, full_obs=full_obs, actor=actor)
        except PlanningError as exc:
            failures.append(f"seed {s}: {exc}")
            continue
        if episode.success:
            episode.extras["attempts"] = attempt + 1  # scalar metadata: 1 + number of rejected maps
            return episode
        failures.append(f"seed {s}: timeout after {episode.length} steps")
    raise EpisodeGenerationError(
        f"no successful '{task}' episode from seed {seed} in {max_retries + 1} attempts: {failures[-3:]}"
    )


def generate_episodes(
    n: int, *, task: str = "makebed", full_obs: bool = True, seed: int = 0
) -> Iterator[Episode]:
    """``n`` successful episodes; episode i starts from ``derive_seed(seed, i)``."""
    if n < 0:
        raise ValueError(f"generate_episodes: n must be >= 0, got {n}")
    for i in range(n):
        yield generate_episode(derive_seed(seed, i), task=task, full_obs=full_obs)
