"""ompn_closed_loop: free-run (closed-loop) evaluation of BC checkpoints.

Examples:

    python -m ompn_ros.cli.closed_loop --domain craft --checkpoint runs/ompn/best --checkpoint runs/lstm/best
    python -m ompn_ros.cli.closed_loop --domain dial --checkpoint runs/dial/best --episodes 10
    python -m ompn_ros.cli.closed_loop --domain craft --checkpoint runs/ompn/best --ros --episodes 5

Craft: --episodes rollouts per task (default tasks makebed, makeaxe, makeshears), success = all 4
subtasks within 64 steps.  Dial: return = subtasks completed (max 4).  In-process evaluation uses
the held-out seeds 10 000 + i (ompn_ros.app.closed_loop); --ros runs sim + ompn_node + monitor
processes (ompn_ros.app.closed_loop_ros), whose seeds are derive_seed(10 000, i).
Prints a table and writes JSON (--json).  Exit codes: 0 ok, 1 ROS run failed, 2 bad arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ompn_ros.app.closed_loop import (
    CRAFT_EVAL_TASKS,
    ClosedLoopReport,
    RandomAgent,
    eval_seeds,
    format_table,
    load_evaluated,
    policy_agent,
    run_closed_loop,
)
from ompn_ros.app.closed_loop_ros import ros_eval_seeds, run_ros_closed_loop
from ompn_ros.app.errors import ClosedLoopError, RosEvalError
from ompn_ros.cli._common import make_parser, run_cli


def build_parser() -> argparse.ArgumentParser:
    p = make_parser("ompn_closed_loop", __doc__.split("\n\n")[0])
    p.add_argument("--domain", choices=("craft", "dial"), required=True, help="which simulator")
    p.add_argument("--checkpoint", action="append", default=[], help="checkpoint directory (repeatable)")
    p.add_argument("--episodes", type=int, default=50, help="episodes (Craft: per task)")
    p.add_argument("--tasks", default=",".join(CRAFT_EVAL_TASKS), help="Craft tasks, comma-separated")
    p.add_argument("--partial-obs", action="store_true", help="Craft: partial observation variant")
    p.add_argument(
        "--max-steps-per-subtask",
        type=int,
        default=None,
        help="Dial per-subtask timeout (none: the simulator's)",
    )
    p.add_argument("--baselines", action="store_true", help="also evaluate a uniformly random policy")
    p.add_argument("--ros", action="store_true", help="run over ROS 2 (sim + ompn_node processes)")
    p.add_argument("--timeout", type=float, default=600.0, help="--ros: seconds per episode")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--json", default=None, help="output JSON (none: closed_loop_<domain>[_ros].json)")
    return p


def _options(args: argparse.Namespace) -> dict[str, Any]:
    if args.domain == "craft":
        return {"tasks": [t for t in args.tasks.split(",") if t], "full_obs": not args.partial_obs}
    return {"max_steps_per_subtask": args.max_steps_per_subtask}


def _ros_options(args: argparse.Namespace) -> dict[str, Any]:
    if args.domain == "craft":
        return {"tasks": _options(args)["tasks"], "sim_params": {"full_obs": not args.partial_obs}}
    if args.max_steps_per_subtask is not None:
        return {"sim_params": {"max_steps_per_subtask": args.max_steps_per_subtask}}
    return {}


def _evaluate(args: argparse.Namespace, meta: dict[str, Any]) -> dict[str, ClosedLoopReport]:
    """Every checkpoint (and the random baseline), in process or over ROS 2."""
    if args.episodes < 1:
        raise ClosedLoopError(f"--episodes must be >= 1, got {args.episodes}")
    if not args.checkpoint and not args.baselines:
        raise ClosedLoopError("give at least one --checkpoint (or --baselines)")
    results: dict[str, ClosedLoopReport] = {}
    names: dict[str, str] = {}
    for path in args.checkpoint:
        policy, meta_record = load_evaluated(path)
        name = f"{policy.config.arch}:{Path(path).resolve().parent.name}/{Path(path).name}"
        names[path] = name if name not in names.values() else f"{name}#{len(names)}"
        meta[names[path]] = meta_record
        if args.ros:
            results[names[path]] = run_ros_closed_loop(
                args.domain, path, episodes=args.episodes, timeout=args.timeout, **_ros_options(args)
            )
        else:
            results[names[path]] = run_closed_loop(
                args.domain, policy_agent(policy), episodes=args.episodes, **_options(args)
            )
    if args.baselines and not args.ros:
        agent = (RandomAgent(n_actions=5, seed=0) if args.domain == "craft"
                 else RandomAgent(action_dim=9, seed=0))  # fmt: skip
        results["random"] = run_closed_loop(args.domain, agent, episodes=args.episodes, **_options(args))
    return results


def _run(args: argparse.Namespace) -> int:
    import torch  # here: --help stays light

    torch.set_num_threads(max(1, args.threads))
    meta: dict[str, Any] = {}
    try:
        results = _evaluate(args, meta)
    except RosEvalError as exc:
        print(f"ompn_closed_loop: {exc}", file=sys.stderr)
        return 1
    print(format_table({name: rep.summary() for name, rep in results.items()}))
    seeds = ros_eval_seeds(args.episodes) if args.ros else eval_seeds(args.episodes)
    out = Path(args.json or f"closed_loop_{args.domain}{'_ros' if args.ros else ''}.json")
    doc = {
        "domain": args.domain,
        "ros": args.ros,
        "episodes": args.episodes,
        "seeds": seeds,
        "options": dict(_options(args)),
        "models": meta,
        "results": {name: rep.to_dict() for name, rep in results.items()},
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2))
    print(f"wrote {out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
