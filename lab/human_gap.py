"""Where the human-like gap comes from (docs/experiments.md §54, #36 item 5): what each perturbation of
the human-like demonstrator costs a trained model, and whether the gap lies in segmenting human-like
episodes or in learning from them.

``quirks``: one checkpoint (default: the domain's shipped one) on held-out episodes of the expert, of
the human-like demonstrator at its defaults, of each perturbation alone and of the defaults without
each one.  ``cross``: own-data runs (:mod:`lab.own_data`) trained on expert or on human-like
demonstrations, each on the same held-out expert and human-like episodes, and (Craft) on the
human-like ones with their idle steps collapsed (:func:`collapse_idle`: a measurement of what a
model input without pauses would give, not a product feature).  ``collapse``: one checkpoint on
held-out expert and human-like episodes with their idle steps collapsed at given tolerances (Dial:
on the joint angles, ``--features 9``).  ``replayed``: own-data runs as the product runs them, offline
and online from the node's replay (the only scoring for a run with ``model.still_tolerance``, §55).
Otherwise offline figures, the
domain's primary detector (Top-K for Craft, the automatic threshold for Dial), teacher-forced from
generated episodes (no bags: dropped and duplicated messages, which only a bag shows, are left out).
Held-out episodes are seeds ``60000 +`` (tasks in turn), used by no run and no tuning.

    python -m lab.human_gap quirks --domain craft
    python -m lab.human_gap cross --work runs/own_data final_craft_full_complete_seed10 \\
        human_craft_full_complete_seed10
    python -m lab.human_gap collapse --domain dial --tolerance 0.004 0.006 --features 9
    python -m lab.human_gap replayed --work runs/own_data human_craft_full_still_seed10
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lab.data import IDLE_TOLERANCE, collapse_idle
from lab.own_data import arm_by_name
from lab.replayed import replayed_figures
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import Episode
from ompn_ros.detect.offline import auto_threshold_boundaries, top_k_boundaries
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.train.evaluation import evaluate, teacher_forced_p_hat
from sim_nodes.human import BOUNDARY_MODE, parse_human
from sim_nodes.registry import default_tasks, expert_episode

SEED_BASE = 60000
_OFF = {"pauses": ("pause_rate=0", "hesitation_rate=0"), "hesitations": ("hesitation_rate=0",),
        "detours": ("overshoot_rate=0", "wrong_move_rate=0"), "noise": ("sensor_noise=0",),
        "tempo": ("speed_range=1:1",)}
_MESSAGES = ("drop_rate=0", "duplicate_rate=0")
def perturbations(domain: str) -> tuple[str, ...]:
    """The perturbations studied in ``domain`` (Craft has one cell per step: no tempo)."""
    return tuple(p for p in _OFF if domain == "dial" or p != "tempo")


def families(domain: str) -> dict[str, tuple[str, ...] | None]:
    """Family name: the human-like parameters changed from the defaults (None: the expert)."""
    names = perturbations(domain)
    out: dict[str, tuple[str, ...] | None] = {"expert": None, "human-like": ()}
    for name in names:
        others = [o for n in names if n != name for o in _OFF[n] if o not in _OFF[name]]
        out[f"{name} only"] = (*others, *_MESSAGES)
        out[f"human-like without {name}"] = _OFF[name]
    out["pauses at boundaries"] = BOUNDARY_MODE  # pauses where people make them (§57)
    return out


def episodes(domain: str, changes: tuple[str, ...] | None, count: int,
             partial: bool = False) -> list[Episode]:
    tasks = default_tasks(domain)
    like = None if changes is None else parse_human(domain, changes)
    return [expert_episode(domain, SEED_BASE + i, task=tasks[i % len(tasks)], partial=partial, human=like)
            for i in range(count)]


def figures(policy: Any, eps: Sequence[Episode]) -> dict[str, float]:
    """Offline alignment and F1@1 (the domain's primary detector), mean episode length and, for
    discrete actions, action accuracy (%)."""
    got = evaluate(policy, eps, keep_p_hat=False)
    out = {"align": round(100 * got["align"], 1), "f1_tol1": round(100 * got["f1_tol1"], 1),
           "mean_steps": round(sum(e.length for e in eps) / len(eps), 1)}
    if "accuracy" in got and got["accuracy"] == got["accuracy"]:  # discrete actions only
        out["accuracy"] = round(100 * float(got["accuracy"]), 1)
    return out


def _boundaries(domain: str, p_hat: np.ndarray, k: int) -> np.ndarray:
    """The domain's primary offline detector: Top-K (Craft), the automatic threshold (Dial)."""
    return top_k_boundaries(p_hat, k) if domain == "craft" else auto_threshold_boundaries(p_hat, k)[0]


def collapsed_figures(policy: Any, eps: Sequence[Episode], domain: str = "craft",
                      tol: float = IDLE_TOLERANCE, features: int | None = None) -> dict[str, float]:
    """The primary detector on the episodes without their idle steps (:func:`collapse_idle`), each
    boundary mapped back to its step and scored against the full episode's labels."""
    short = [collapse_idle(ep, tol, features) for ep in eps]
    p_hats, _ = teacher_forced_p_hat(policy, [s for s, _ in short])
    preds = [np.unique(np.append(kept[_boundaries(domain, p, len(ep.boundaries))], ep.length - 1))
             for p, (_, kept), ep in zip(p_hats, short, eps, strict=True)]
    labels = [np.asarray(ep.subtask) for ep in eps]
    kept_share = sum(len(k) for _, k in short) / sum(ep.length for ep in eps)
    return {"align": round(100 * alignment_accuracy(preds, labels, variant="authors"), 1),
            "f1_tol1": round(100 * mean_f1(preds, [ep.boundaries for ep in eps], 1).f1, 1),
            "idle_share": round(100 * (1.0 - kept_share), 1)}


def collapse(domain: str, checkpoint: Path, count: int, tols: Sequence[float],
             features: int | None) -> list[dict[str, Any]]:
    """The checkpoint on held-out expert and human-like episodes, as they are and with their idle
    steps collapsed at each tolerance."""
    policy, _ = load_checkpoint(checkpoint)
    rows = []
    for family in ("expert", "human-like"):
        eps = episodes(domain, families(domain)[family], count)
        rows.append({"domain": domain, "family": family, "as_is": figures(policy, eps),
                     "collapsed": {str(t): collapsed_figures(policy, eps, domain, t, features) for t in tols},
                     "features": features})
    return rows


def quirks(domain: str, checkpoint: Path, count: int, partial: bool) -> list[dict[str, Any]]:
    policy, _ = load_checkpoint(checkpoint)
    return [{"domain": domain, "checkpoint": str(checkpoint), "family": name, "episodes": count,
             **figures(policy, episodes(domain, changes, count, partial))}
            for name, changes in families(domain).items()]


def default_count(domain: str) -> int:
    """Held-out episodes per family: Craft 150, Dial 60 (Dial's episodes are 7-10 times longer)."""
    return 150 if domain == "craft" else 60


HELD_OUT = ("expert", "human-like")
"""The families the own-data runs are scored on by default (any of :func:`families` can be asked for)."""


def held_out(domain: str, partial: bool, count: int, names: Sequence[str] = HELD_OUT
             ) -> dict[str, list[Episode]]:
    """Held-out episodes of a domain and observation (seeds ``SEED_BASE +``), per family of `quirks`."""
    known = families(domain)
    return {name: episodes(domain, known[name], count, partial) for name in names}


def arms_held_out(arms: Sequence[str], count: int | None, names: Sequence[str] = HELD_OUT
                  ) -> Iterator[tuple[Any, dict[str, list[Episode]]]]:
    """Each own-data arm with the held-out episodes of ``names`` of its domain and observation (``count``
    each, default :func:`default_count`), generated once per domain and observation."""
    held: dict[tuple[str, bool], dict[str, list[Episode]]] = {}
    for name in arms:
        arm = arm_by_name(name)
        key = (arm.domain, arm.partial)
        if key not in held:
            held[key] = held_out(arm.domain, arm.partial, count or default_count(arm.domain), names)
        yield arm, held[key]


def replayed(work: Path, arms: Sequence[str], count: int | None, names: Sequence[str] = HELD_OUT
             ) -> list[dict[str, Any]]:
    """One row per own-data run: offline and online figures as the product gives them
    (:func:`lab.replayed.replayed_figures`: the node's replay with ``ompn_train``'s detector), on the
    held-out episodes of ``names`` (default: expert and human-like) of its domain and observation (§55)."""
    rows = []
    for arm, held in arms_held_out(arms, count, names):
        checkpoint = work / "runs" / arm.name / "best"
        scored = {family: replayed_figures(checkpoint, arm.domain, eps) for family, eps in held.items()}
        rows.append({"arm": arm.name, "trained_on": arm.demonstrator, "still_tolerance": arm.still,
                     "episodes": count or default_count(arm.domain), **scored})
    return rows


def cross(work: Path, arms: Sequence[str], count: int | None) -> list[dict[str, Any]]:
    """One row per own-data run: its figures on held-out expert and human-like episodes of its
    domain and observation (``count`` each, default :func:`default_count`)."""
    rows = []
    for arm, held in arms_held_out(arms, count):
        policy, _ = load_checkpoint(work / "runs" / arm.name / "best")
        row = {"arm": arm.name, "trained_on": arm.demonstrator, "episodes": len(held["expert"]),
               **{family: figures(policy, eps) for family, eps in held.items()}}
        if arm.domain == "craft":
            row["human-like, idle steps collapsed"] = collapsed_figures(policy, held["human-like"])
        rows.append(row)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="study", required=True)
    q = sub.add_parser("quirks", help="one checkpoint on each perturbation family")
    q.add_argument("--domain", choices=("craft", "dial"), default="craft")
    q.add_argument("--checkpoint", type=Path, default=None, help="default: the domain's shipped checkpoint")
    q.add_argument("--partial", action="store_true", help="Craft's partial observation")
    c = sub.add_parser("cross", help="own-data runs on expert and human-like held-out episodes")
    c.add_argument("--work", type=Path, required=True)
    c.add_argument("arms", nargs="+")
    r = sub.add_parser("replayed", help="own-data runs through the node's replay (offline and online)")
    r.add_argument("--work", type=Path, required=True)
    r.add_argument("arms", nargs="+")
    r.add_argument("--families", nargs="+", default=list(HELD_OUT),
                   help="families of `quirks` (default: %(default)s)")
    k = sub.add_parser("collapse", help="one checkpoint on held-out episodes with idle steps collapsed")
    k.add_argument("--domain", choices=("craft", "dial"), default="craft")
    k.add_argument("--checkpoint", type=Path, default=None, help="default: the domain's shipped checkpoint")
    k.add_argument("--tolerance", type=float, nargs="+", default=[IDLE_TOLERANCE])
    k.add_argument("--features", type=int, default=None, help="watch the first N features only")
    for p in (q, c, r, k):
        p.add_argument("--episodes", type=int, default=None, help="held-out episodes (Craft 150, Dial 60)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.study == "quirks":
        count = args.episodes or default_count(args.domain)
        rows = quirks(args.domain, args.checkpoint or shipped_checkpoint(args.domain), count, args.partial)
    elif args.study == "collapse":
        rows = collapse(args.domain, args.checkpoint or shipped_checkpoint(args.domain),
                        args.episodes or default_count(args.domain), args.tolerance, args.features)
    elif args.study == "replayed":
        rows = replayed(args.work, args.arms, args.episodes, args.families)
    else:
        rows = cross(args.work, args.arms, args.episodes)
    for row in rows:
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
