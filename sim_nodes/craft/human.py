"""The human-like Craft demonstrator (docs/craft.md §2.6): the expert bot with pauses, hesitations,
overshoots and wrong moves undone; then sensor noise and dropped or duplicated observation messages.

Only a step on which the expert *moves* is ever replaced, so the bot's own bookkeeping (a workshop
counts as used only right after its USE) is never fooled, and every replacement is exact:

* a pause or hesitation step is a no-op: USE facing an empty cell or the boundary, otherwise a move
  toward the (occupied) cell faced, which only turns the agent to where it already looks;
* an overshoot takes the expert's move, one more cell the same way, then one back (only when both
  cells are empty); a wrong move takes one step to another empty side and back;
* a sidetrack (``boundary_rate``) at a subtask change queues a pause, and the new subtask's first moves
  try its correction until one fits (an overshoot needs two empty cells ahead, a wrong move an empty
  side).

The bot plans afresh from wherever the agent stands afterwards.  Labels come from the world, so a
detour belongs to the subtask in progress.
"""

from __future__ import annotations

from collections.abc import Callable

from ompn_ros.data.episode import Episode
from sim_nodes.craft.expert import ExpertBot, bot_observation, generate_episode
from sim_nodes.craft.world import BOUNDARY, DIRECTION_DELTA, EMPTY, Action, CraftWorld
from sim_nodes.human import EVENTS_KEY, HumanLike, behaviour_rng, new_events, record_faults

_OPPOSITE = (int(Action.UP), int(Action.DOWN), int(Action.RIGHT), int(Action.LEFT))
_PAUSE = -1


def _empty(world: CraftWorld, cell: tuple[int, int]) -> bool:
    return bool(world.grid[cell] == EMPTY)


def _ahead(cell: tuple[int, int], direction: int) -> tuple[int, int]:
    dx, dy = DIRECTION_DELTA[direction]
    return cell[0] + dx, cell[1] + dy


class _HumanCraft:
    """One episode's human-like actor: a queue of pending actions in front of the expert bot."""

    def __init__(self, world: CraftWorld, bot: ExpertBot, human: HumanLike, seed: int) -> None:
        self.world, self.bot, self.human = world, bot, human
        self.rng = behaviour_rng(seed)
        self.queue: list[int] = []
        self.subtask_seen = -1
        self.sidetrack: str | None = None  # the correction a sidetrack still owes ('overshoot' | 'wrong')
        self.events = new_events()

    def _pause(self, kind: str) -> None:
        length = self.human.pause_length(self.rng)
        self.events[kind] += 1
        self.events["pause_steps"] += length
        self.queue.extend([_PAUSE] * length)

    def _no_op(self) -> int:
        world = self.world
        if int(world.grid[world.front]) in (EMPTY, BOUNDARY):
            return int(Action.USE)
        return int(world.direction)

    def _detour(self, move: int) -> None:
        """After the expert chose ``move``: maybe queue an overshoot or a wrong move instead (a sidetrack's
        correction first, when one is owed)."""
        h = self.human
        if self.sidetrack is not None:
            if self._correct(move, self.sidetrack):
                self.sidetrack = None
            return
        self.events["opportunities_detour"] += 1
        draw = self.rng.random()
        if draw < h.overshoot_rate:
            self._correct(move, "overshoot")
        elif draw < h.overshoot_rate + h.wrong_move_rate:
            self._correct(move, "wrong")

    def _correct(self, move: int, kind: str) -> bool:
        """Queue an overshoot of ``move`` or a wrong move undone, if the cells allow it."""
        world = self.world
        if kind == "overshoot":
            first = _ahead(world.pos, move)
            if _empty(world, first) and _empty(world, _ahead(first, move)):
                self.events["overshoots"] += 1
                self.queue.extend([move, move, _OPPOSITE[move]])
                return True
            return False
        sides = [d for d in range(4) if d != move and _empty(world, _ahead(world.pos, d))]
        if not sides:
            return False
        wrong = sides[int(self.rng.integers(len(sides)))]
        self.events["wrong_moves"] += 1
        self.queue.extend([wrong, _OPPOSITE[wrong]])
        return True

    def _changed(self) -> None:
        """A new subtask: maybe a sidetrack (``boundary_rate``, not at the first subtask), then maybe a
        hesitation."""
        h = self.human
        if h.boundary_rate > 0 and self.subtask_seen >= 0:
            self.events["opportunities_sidetrack"] += 1
            self.sidetrack = None
            if self.rng.random() < h.boundary_rate:
                self.events["sidetracks"] += 1
                self._pause("pauses")
                self.sidetrack = h.correction(self.rng)
        self.subtask_seen = self.world.sketch_index
        self.events["opportunities_hesitation"] += 1
        if self.rng.random() < h.hesitation_rate:
            self._pause("hesitations")

    def _plan(self) -> int:
        move = self.bot.act(bot_observation(self.world, self.bot.full_obs))
        if move >= int(Action.USE):
            return move  # USE and DONE are never replaced
        h = self.human
        if self.world.sketch_index != self.subtask_seen:
            self._changed()
        if not self.queue:
            self.events["opportunities_pause"] += 1
            if self.rng.random() < h.pause_rate:
                self._pause("pauses")
        if not self.queue:
            self._detour(move)
        return move if not self.queue else self.queue.pop(0)

    def __call__(self) -> int:
        action = self.queue.pop(0) if self.queue else self._plan()
        return self._no_op() if action == _PAUSE else action


class HumanCraftActor:
    """An ``actor`` for :func:`~sim_nodes.craft.expert.rollout`; keeps the last episode's events."""

    def __init__(self, human: HumanLike) -> None:
        self.human = human
        self.last: _HumanCraft | None = None

    def __call__(self, world: CraftWorld, bot: ExpertBot, seed: int) -> Callable[[], int]:
        self.last = _HumanCraft(world, bot, self.human, seed)
        return self.last


def generate_human_episode(
    seed: int, human: HumanLike, *, task: str = "makebed", full_obs: bool = True, max_retries: int = 100
) -> Episode:
    """A successful human-like episode (retries as :func:`~sim_nodes.craft.expert.generate_episode`),
    with sensor noise and ``extras['observation_copies']`` (:func:`sim_nodes.human.record_faults`)."""
    actor = HumanCraftActor(human)
    episode = generate_episode(seed, task=task, full_obs=full_obs, max_retries=max_retries, actor=actor)
    assert actor.last is not None
    episode.extras[EVENTS_KEY] = dict(actor.last.events)
    episode.extras["demonstrator"] = "human"
    return record_faults(episode, human, episode.seed)
