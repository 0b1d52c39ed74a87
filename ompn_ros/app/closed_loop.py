"""Closed-loop (free-run) evaluation of a behaviour-cloned policy in the env, ROS-free.

The policy acts on its own observations (no teacher forcing), as in the authors' free-run
evaluation (docs/craft.md §4, docs/dial.md §2.6; paper Fig. 6):

* **Craft**: greedy rollout of at most 64 steps; the action is the argmax over the env actions
  (the policy's ``StepOutput.action``; DONE is a no-op in the env, so done is never taken).
  *Success* = all 4 subtasks of the sketch completed (goal item held) within the limit.
* **Dial**: the Gaussian mean is executed (clipped to [-1, 1] by the env) until the sketch is
  complete or a subtask times out (``max_steps_per_subtask``, env default 500).  *Return* =
  number of subtasks completed (max 4), *success* = return 4.

**Seeds.** Evaluation episode i uses seed ``EVAL_SEED_BASE + i`` (10 000, 10 001, ...).  Training data
uses ``derive_seed(data_seed, i)`` (``sim_nodes.derive_seed``: hashed seeds in 0..2^31-1) and
``generate_episode``'s retries use ``derive_seed(seed, k, stream=1)``; the evaluation seeds are a
separate contiguous block never requested by the collectors, so evaluation maps/initial poses are
held out (a hash landing in 10 000..10 000+N is possible only by chance, p ~ N·n_train / 2^31).

Any object with ``reset(sketch)`` and ``step(obs) -> obj.action`` is an agent: a
:class:`~ompn_ros.model.streaming.StreamingPolicy`, the LSTM stepper, :class:`ReplayAgent`,
:class:`RandomAgent`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ompn_ros.app.errors import ClosedLoopError
from ompn_ros.data.cuts import StillRuns, still_runs
from sim_nodes.registry import CRAFT_TASKS, CraftEnv, DialEnv, dial_episode_sketch

if TYPE_CHECKING:  # the model (torch) loads with the first checkpoint, not for ompn_closed_loop --help
    from ompn_ros.model.build import PolicyModule

EVAL_SEED_BASE = 10_000
"""First evaluation seed; see the module docstring."""
CRAFT_EVAL_TASKS: tuple[str, ...] = ("makebed", "makeaxe", "makeshears")


class Agent(Protocol):
    """What the evaluator drives: ``reset`` at every episode start, ``step`` on every observation."""

    def reset(self, sketch: np.ndarray | None = None) -> None: ...

    def step(self, obs: np.ndarray) -> Any: ...


@dataclass(frozen=True)
class Action:
    """Minimal step output for the scripted agents (the evaluator reads only ``action``)."""

    action: Any


@dataclass
class EpisodeResult:
    """One closed-loop episode: ``subtasks_done`` is the return (Craft: sketch index reached).

    ``actions``: the executed discrete actions when recording was requested (Craft), else None.
    """

    domain: str
    task: str
    seed: int
    success: bool
    subtasks_done: int
    n_subtasks: int
    length: int
    actions: list[int] | None = None


@dataclass
class ClosedLoopReport:
    """All episodes of one evaluation and their summary (see :meth:`summary`)."""

    domain: str
    episodes: list[EpisodeResult] = field(default_factory=list)
    seconds: float = 0.0

    def summary(self) -> dict[str, Any]:
        """``success_rate``, ``mean_return`` (subtasks done), ``mean_length``, per task, and overall."""

        def block(eps: list[EpisodeResult]) -> dict[str, float]:
            return {
                "episodes": float(len(eps)),
                "success_rate": float(np.mean([e.success for e in eps])) if eps else float("nan"),
                "mean_return": float(np.mean([e.subtasks_done for e in eps])) if eps else float("nan"),
                "mean_length": float(np.mean([e.length for e in eps])) if eps else float("nan"),
            }

        tasks = sorted({e.task for e in self.episodes})
        return {
            "domain": self.domain,
            **block(self.episodes),
            "per_task": {t: block([e for e in self.episodes if e.task == t]) for t in tasks},
            "seconds": self.seconds,
        }

    def to_dict(self) -> dict[str, Any]:
        return {"summary": self.summary(), "episodes": [asdict(e) for e in self.episodes]}


def eval_seeds(n: int, base: int = EVAL_SEED_BASE) -> list[int]:
    """The ``n`` held-out evaluation seeds ``base, base + 1, ...``."""
    if not isinstance(n, int) or n < 1:
        raise ClosedLoopError(f"number of evaluation episodes must be a positive int, got {n!r}")
    return list(range(base, base + n))


def load_evaluated(path: str | Path) -> tuple[PolicyModule, dict[str, Any]]:
    """The policy of checkpoint ``path`` and its record in the evaluation report (the checkpoint, its
    model config and the training iteration it was saved at)."""
    from ompn_ros.model.checkpoint import load_checkpoint

    policy, extra = load_checkpoint(path)
    record = {"checkpoint": str(path), "config": policy.config.to_dict(), "iteration": extra.get("iteration")}
    return policy, record


def policy_agent(policy: PolicyModule) -> Agent:
    """The in-process agent of ``policy``: its streaming stepper
    (:func:`ompn_ros.model.load.build_stepper`), behind the still rule when the model has one."""
    from ompn_ros.model.load import build_stepper

    stepper = build_stepper(policy)
    runs = still_runs(float(getattr(policy.config, "still_tolerance", 0.0)))
    return StillAgent(stepper, runs) if runs is not None else stepper


class StillAgent:
    """A model with ``still_tolerance`` in the loop: an observation that moved nothing since the last
    stepped one is not stepped (:meth:`ompn_ros.data.cuts.StillRuns.apply`, as in training and
    ``ompn_node``) and the last step's output, its action included, is given again."""

    def __init__(self, stepper: Any, runs: StillRuns) -> None:
        self.stepper, self.config = stepper, stepper.config
        self.runs = runs
        self.last: Any = None

    def reset(self, sketch: np.ndarray | None = None) -> None:
        self.stepper.reset(sketch)
        self.runs.reset()
        self.last = None

    def step(self, obs: np.ndarray) -> Any:
        """A step of the model when ``obs`` moved, else the last step's output again."""
        out = self.runs.apply(np.asarray(obs, dtype=np.float32).ravel(), 0, lambda _: self.stepper.step(obs))
        if out is None and self.last is None:  # still, yet no output to repeat (the last step raised)
            out = self.stepper.step(obs)
        if out is not None:
            self.last = out
        return self.last


def agent_uses_sketch(agent: Any) -> bool:
    """True unless the agent has a ``config`` whose ``sketch_mode`` is ``'none'``."""
    config = getattr(agent, "config", None)
    return config is None or getattr(config, "sketch_mode", "sum") != "none"


# --- Craft ----------------------------------------------------------------------------------------


def run_craft_episode(agent: Agent, task: str, seed: int, *, full_obs: bool = True, use_sketch: bool = True,
                      max_steps: int = 64, record_actions: bool = False) -> EpisodeResult:  # fmt: skip
    """One greedy Craft rollout of ``agent`` on map ``seed`` (``CraftEnv.reset(seed=seed)``)."""
    env = CraftEnv(task, full_obs=full_obs, max_steps=max_steps)
    obs, info = env.reset(seed=seed)
    agent.reset(np.asarray(env.sketch, dtype=np.int64) if use_sketch else None)
    steps, terminated, truncated = 0, False, False
    actions: list[int] = []
    while not (terminated or truncated):
        action = int(agent.step(obs).action)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
    return EpisodeResult(
        domain="craft",
        task=task,
        seed=seed,
        success=bool(info["success"]),
        subtasks_done=int(info["sketch_index"]),
        n_subtasks=len(env.sketch),
        length=steps,
        actions=actions if record_actions else None,
    )


def run_craft(
    agent: Agent,
    *,
    episodes: int = 30,
    tasks: Sequence[str] = CRAFT_EVAL_TASKS,
    seeds: Sequence[int] | None = None,
    full_obs: bool = True,
    use_sketch: bool | None = None,
    max_steps: int = 64,
    record_actions: bool = False,
) -> ClosedLoopReport:
    """``episodes`` rollouts per task (seeds :func:`eval_seeds` unless given) -> report."""
    unknown = [t for t in tasks if t not in CRAFT_TASKS]
    if unknown or not tasks:
        raise ClosedLoopError(f"unknown Craft tasks {unknown or list(tasks)}; known: {sorted(CRAFT_TASKS)}")
    seed_list = list(seeds) if seeds is not None else eval_seeds(episodes)
    sketch = agent_uses_sketch(agent) if use_sketch is None else use_sketch
    report = ClosedLoopReport("craft")
    start = time.perf_counter()
    for task in tasks:
        for seed in seed_list:
            report.episodes.append(
                run_craft_episode(
                    agent,
                    task,
                    seed,
                    full_obs=full_obs,
                    use_sketch=sketch,
                    max_steps=max_steps,
                    record_actions=record_actions,
                )
            )
    report.seconds = time.perf_counter() - start
    return report


# --- Dial -----------------------------------------------------------------------------------------


def run_dial(
    agent: Agent,
    *,
    episodes: int = 10,
    seeds: Sequence[int] | None = None,
    sketches: Sequence[Sequence[int]] | None = None,
    use_sketch: bool | None = None,
    max_steps_per_subtask: int | None = None,
) -> ClosedLoopReport:
    """Dial rollouts: ``DialEnv.reset(seed=seed)`` with the sketch ``episode_sketch(seed)`` (as the
    collector and ``dial_sim`` draw it) unless ``sketches`` is given."""
    seed_list = list(seeds) if seeds is not None else eval_seeds(episodes)
    if sketches is not None and len(sketches) != len(seed_list):
        raise ClosedLoopError(f"got {len(sketches)} sketches for {len(seed_list)} seeds")
    env = DialEnv() if max_steps_per_subtask is None else DialEnv(max_steps_per_subtask=max_steps_per_subtask)
    sketch_on = agent_uses_sketch(agent) if use_sketch is None else use_sketch
    report = ClosedLoopReport("dial")
    start = time.perf_counter()
    for i, seed in enumerate(seed_list):
        sketch = list(sketches[i]) if sketches is not None else dial_episode_sketch(seed).tolist()
        obs, info = env.reset(seed=seed, options={"sketch": sketch})
        agent.reset(np.asarray(info["sketch"], dtype=np.int64) if sketch_on else None)
        steps, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            action = np.asarray(agent.step(obs).action, dtype=np.float32)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
        report.episodes.append(
            EpisodeResult(
                domain="dial",
                task="dial",
                seed=seed,
                success=bool(info["is_success"]),
                subtasks_done=int(info["subtasks_done"]),
                n_subtasks=env.sketch_length,
                length=steps,
            )
        )
    report.seconds = time.perf_counter() - start
    return report


def run_closed_loop(domain: str, agent: Agent, *, episodes: int, **options: Any) -> ClosedLoopReport:
    """Dispatch to :func:`run_craft` or :func:`run_dial`."""
    if domain == "craft":
        return run_craft(agent, episodes=episodes, **options)
    if domain == "dial":
        return run_dial(agent, episodes=episodes, **options)
    raise ClosedLoopError(f"domain must be 'craft' or 'dial', got {domain!r}")


# --- scripted agents ------------------------------------------------------------------------------


class ReplayAgent:
    """Open-loop replay of recorded action sequences: episode k of the evaluation replays ``actions[k]``.

    After a sequence is exhausted it returns ``fallback`` (Craft: DONE = 5, a no-op; Dial: zeros).
    Used to check that the evaluator counts a known-good trajectory as a success.
    """

    def __init__(self, actions: Sequence[np.ndarray], fallback: Any) -> None:
        self.actions = [np.asarray(a) for a in actions]
        self.fallback = fallback
        self.episode = -1
        self.t = 0

    def reset(self, sketch: np.ndarray | None = None) -> None:
        self.episode += 1
        if self.episode >= len(self.actions):
            raise ClosedLoopError(f"ReplayAgent has only {len(self.actions)} recorded episodes")
        self.t = 0

    def step(self, obs: np.ndarray) -> Action:
        seq = self.actions[self.episode]
        action = seq[self.t] if self.t < len(seq) else self.fallback
        self.t += 1
        return Action(action)


class RandomAgent:
    """Uniformly random env actions (Craft: 0..n_actions-1; Dial: uniform in [-1, 1]^dim)."""

    def __init__(self, *, n_actions: int | None = None, action_dim: int | None = None, seed: int = 0) -> None:
        if (n_actions is None) == (action_dim is None):
            raise ClosedLoopError("RandomAgent needs exactly one of n_actions (discrete) or action_dim")
        self.n_actions, self.action_dim = n_actions, action_dim
        self.rng = np.random.default_rng(seed)

    def reset(self, sketch: np.ndarray | None = None) -> None:
        return None

    def step(self, obs: np.ndarray) -> Action:
        if self.n_actions is not None:
            return Action(int(self.rng.integers(self.n_actions)))
        assert self.action_dim is not None
        return Action(self.rng.uniform(-1.0, 1.0, self.action_dim).astype(np.float32))


def format_table(rows: dict[str, dict[str, Any]]) -> str:
    """A plain-text table of ``{name: summary}`` (success rate, mean return, mean length, episodes)."""
    header = f"{'policy':<28} {'success':>8} {'return':>7} {'length':>7} {'episodes':>8}"
    lines = [header, "-" * len(header)]
    for name, s in rows.items():
        lines.append(
            f"{name:<28} {s['success_rate']:>8.3f} {s['mean_return']:>7.2f} {s['mean_length']:>7.1f} "
            f"{int(s['episodes']):>8d}"
        )
        for task, t in s.get("per_task", {}).items():
            if len(s.get("per_task", {})) > 1:
                lines.append(
                    f"  {task:<26} {t['success_rate']:>8.3f} {t['mean_return']:>7.2f} "
                    f"{t['mean_length']:>7.1f} {int(t['episodes']):>8d}"
                )
    return "\n".join(lines)
