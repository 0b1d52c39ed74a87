"""Detours in human-like demonstrations: what a move and its reversal do to the memory, and remedies
against them, each against a DROID-style idle filter (docs/experiments.md §57).

A detour (an overshoot, a wrong move undone: docs/craft.md §2.6) changes the observation twice and
returns it, so the still rule (:mod:`ompn_ros.data.cuts.still`) cannot see it.  ``memory``: where the
shipped Craft checkpoint puts its boundary score (Top-K's expected expansion height over the memory
depth, 0 to 1: the memory is told to close a subtask) on detour steps, against true boundaries and
ordinary steps, and what share of its Top-K boundaries fall on a detour.  ``remedies``: a checkpoint
on held-out episodes of each family with
what the model sees or how its boundaries are chosen changed, label-free and from the observations
alone, offline (Top-K alignment and F1@1, teacher-forced):

* ``as is``;
* ``droid``: the baseline of large robot datasets (DROID's idle filter): a frame is idle when every
  element of its velocity changed by less than 1e-3 since the previous frame (Craft: the observation's
  change per step is its velocity; Dial: the recorded joint velocities), and runs of at least 7 idle
  frames are dropped;
* ``still``: the product's still rule at ``still_tolerance: auto`` chosen from the family's episodes;
* ``fold``: an offline pass that folds a trip out and back: an observation within T of one of the last
  :data:`FOLD_WINDOW` kept observations undoes what followed it, which is dropped (the still rule is
  its window of 1); T is auto's noise-floor tolerance even where auto keeps 0 for want of still steps
  (a family without pauses still has detours);
* ``persist``: the still rule, and a boundary needs the new subtask's evidence to persist: a step
  whose move, or the next step's move, is undone within :data:`PERSIST_STEPS` steps (the observation
  returns within T of the one before it) cannot end a subtask (online, a delay of that many steps);
* ``fold + persist``: both.

Every dropped row joins the run of the kept row before it and a boundary is placed at the last row of
its run, as the still rule places it.  Held-out episodes are :mod:`lab.human_gap`'s (seeds 60000 +).

    python -m lab.detours memory
    python -m lab.detours remedies --domain craft [--checkpoint DIR]
    python -m lab.detours collate --out results/detours.json memory.jsonl craft.jsonl ... [--arm A.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lab.human_gap import SEED_BASE, _boundaries, default_count
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.cuts import choose_tolerance, drop_still, noise_margin, run_ends
from ompn_ros.data.episode import Episode
from ompn_ros.detect.offline import depth_scores, top_k_boundaries
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.train.evaluation import teacher_forced_p_hat
from sim_nodes.craft.world import Action
from sim_nodes.human import BOUNDARY_MODE, parse_human
from sim_nodes.registry import default_tasks, expert_episode

FOLD_WINDOW = 4
"""Kept observations an observation is compared with by ``fold`` (an overshoot returns after 3 moves)."""
PERSIST_STEPS = 3
"""Steps within which an undone move voids a boundary (``persist``)."""
DROID_DELTA, DROID_RUN = 1e-3, 7
"""DROID's idle filter: every |Δ velocity| below 1e-3, runs of at least 7 frames dropped."""
FAMILIES: dict[str, tuple[str, ...] | None] = {
    "expert": None,
    "human-like": (),
    "human-like without pauses": ("pause_rate=0", "hesitation_rate=0"),
    "pauses at boundaries": BOUNDARY_MODE,
}
"""The families scored (the demonstrator's parameters changed from its defaults; None: the expert)."""
_OPPOSITE = {int(Action.DOWN): int(Action.UP), int(Action.UP): int(Action.DOWN),
             int(Action.LEFT): int(Action.RIGHT), int(Action.RIGHT): int(Action.LEFT)}


def family_episodes(domain: str, changes: tuple[str, ...] | None, count: int) -> list[Episode]:
    tasks = default_tasks(domain)
    like = None if changes is None else parse_human(domain, changes)
    return [expert_episode(domain, SEED_BASE + i, task=tasks[i % len(tasks)], human=like)
            for i in range(count)]


def detour_steps(ep: Episode) -> np.ndarray:
    """Per real step of a Craft episode, whether it is a move or the move that reverses it right after."""
    acts = np.asarray(ep.actions, dtype=np.int64)
    out = np.zeros(ep.length, dtype=bool)
    for t in range(ep.length - 1):
        if int(acts[t]) in _OPPOSITE and _OPPOSITE[int(acts[t])] == int(acts[t + 1]):
            out[t] = out[t + 1] = True
    return out


def memory(policy: Any, eps: Sequence[Episode]) -> dict[str, float]:
    """Mean boundary score on detour steps, true boundaries and the other steps; the share of
    Top-K boundaries on a detour step against the share of steps that are detour steps (%)."""
    p_hats, _ = teacher_forced_p_hat(policy, eps)
    on: dict[str, list[float]] = {"detour": [], "boundary": [], "other": []}
    hits = picks = 0
    for p, ep in zip(p_hats, eps, strict=True):
        arr = np.asarray(p, dtype=np.float64)
        close = depth_scores(arr) / (arr.shape[1] - 1)
        detour, bound = detour_steps(ep), np.zeros(ep.length, dtype=bool)
        bound[np.asarray(ep.boundaries, dtype=np.int64)] = True
        on["detour"] += list(close[detour & ~bound])
        on["boundary"] += list(close[bound])
        on["other"] += list(close[~detour & ~bound])
        chosen = top_k_boundaries(np.asarray(p), len(ep.boundaries))
        inner = chosen[~bound[chosen]]
        hits, picks = hits + int(detour[inner].sum()), picks + len(chosen)
    steps = sum(ep.length for ep in eps)
    return {**{f"score_{k}": round(float(np.mean(v)), 4) if v else float("nan") for k, v in on.items()},
            "detour_step_share": round(100 * len(on["detour"]) / steps, 1),
            "topk_on_detour_share": round(100 * hits / max(picks, 1), 1)}


def fold_rows(obs: np.ndarray, tolerance: float, window: int) -> np.ndarray:
    """The first row of each run after folding (module docstring): a row within ``tolerance`` (every
    element) of one of the last ``window`` kept rows drops the kept rows after that one and joins its
    run.  A walk back the way it came unwinds the same way (without labels it looks like a detour).  Row
    0 is always kept.  O(T · window)."""
    kept = [0]
    for t in range(1, len(obs)):
        back = None
        for j in range(len(kept) - 1, max(len(kept) - 1 - window, -1), -1):
            if np.all(np.abs(obs[t] - obs[kept[j]]) < tolerance):
                back = j
                break
            if np.all(np.abs(obs[t] - obs[kept[j]]) < tolerance):
                back = j
                break
        if back is None:
            kept.append(t)
        else:
            del kept[back + 1:]
    return np.asarray(kept, dtype=np.int64)


def droid_rows(ep: Episode, domain: str) -> np.ndarray:
    """The first row of each run after DROID's idle filter: runs of at least :data:`DROID_RUN` frames whose
    velocity changed by less than :data:`DROID_DELTA` in every element are dropped (their rows join the
    run before them; the first row is always kept)."""
    T = ep.length
    if domain == "dial" and "joint_velocity" in ep.extras:
        velocity = np.asarray(ep.extras["joint_velocity"], dtype=np.float64)[:T]
    else:
        velocity = np.diff(np.asarray(ep.observations[: T + 1], dtype=np.float64), axis=0)[:T]
    idle = np.zeros(T, dtype=bool)
    idle[1:] = np.all(np.abs(np.diff(velocity, axis=0)) < DROID_DELTA, axis=1)
    drop = np.zeros(T, dtype=bool)
    t = 0
    while t < T:
        if not idle[t]:
            t += 1
            continue
        end = t
        while end < T and idle[end]:
            end += 1
        if end - t >= DROID_RUN:
            drop[t:end] = True
        t = end
    drop[0] = False
    return np.flatnonzero(~drop)


def undone(obs: np.ndarray, tolerance: float, steps: int) -> np.ndarray:
    """Per row t, whether the move of step t or of step t + 1 is undone: the observation returns within
    ``tolerance`` of the one before that move within ``steps`` rows after it (its new state does not
    persist, so no new subtask began there)."""
    T = len(obs) - 1
    moved_back = np.zeros(T + 1, dtype=bool)
    for t in range(T):
        for s in range(t + 2, min(t + 2 + steps, len(obs))):
            if np.all(np.abs(obs[s] - obs[t]) < tolerance):
                moved_back[t] = True
                break
    return moved_back[:T] | moved_back[1:]


def reduce(ep: Episode, firsts: np.ndarray) -> Episode:
    """``ep`` stepped only on ``firsts`` (each run's step takes its last row's action and label)."""
    last = run_ends(firsts, ep.length)
    obs_rows = np.append(firsts, ep.length)
    return Episode(np.ascontiguousarray(ep.observations[obs_rows]), np.ascontiguousarray(ep.actions[last]),
                   None if ep.subtask is None else ep.subtask[last], ep.sketch, ep.task, ep.seed, ep.success)


Arm = Callable[[Episode], tuple[np.ndarray, np.ndarray | None]]


def arms(domain: str, tolerance: float, fold_t: float) -> dict[str, Arm]:
    """Each remedy as ``episode -> (first rows of the runs the model steps, steps barred from ending a
    subtask or None)``: the still rule at ``tolerance``, folds and the persistence test at ``fold_t``."""
    def still(ep: Episode) -> np.ndarray:
        return drop_still(ep, tolerance)[1] if tolerance > 0 else np.arange(ep.length)

    def fold(ep: Episode) -> np.ndarray:
        return fold_rows(ep.observations[: ep.length], fold_t, FOLD_WINDOW) if fold_t > 0 else \
            np.arange(ep.length)

    def barred(ep: Episode) -> np.ndarray | None:
        return undone(ep.observations[: ep.length + 1], fold_t, PERSIST_STEPS) if fold_t > 0 else None

    return {"as is": lambda ep: (np.arange(ep.length), None),
            "droid": lambda ep: (droid_rows(ep, domain), None),
            "still": lambda ep: (still(ep), None),
            "fold": lambda ep: (fold(ep), None),
            "persist": lambda ep: (still(ep), barred(ep)),
            "fold + persist": lambda ep: (fold(ep), barred(ep))}


def score(policy: Any, domain: str, eps: Sequence[Episode], arm: Arm) -> dict[str, float]:
    """The domain's primary offline detector on the reduced episodes, each boundary at the last row of its
    run (a barred row's run cannot end a subtask), scored on the full episodes' labels."""
    plans = [arm(ep) for ep in eps]
    p_hats, _ = teacher_forced_p_hat(policy, [reduce(ep, firsts) for ep, (firsts, _) in zip(eps, plans,
                                                                                            strict=True)])
    preds = []
    for p, ep, (firsts, barred) in zip(p_hats, eps, plans, strict=True):
        p = np.array(p, dtype=np.float64)
        ends = run_ends(firsts, ep.length)
        if barred is not None:
            p[barred[ends]] = np.eye(p.shape[1])[-1]  # all on the bottom slot: no boundary
        preds.append(np.unique(np.append(ends[_boundaries(domain, p, len(ep.boundaries))], ep.length - 1)))
    labels = [np.asarray(ep.subtask) for ep in eps]
    kept = sum(len(f) for f, _ in plans) / sum(ep.length for ep in eps)
    return {"align": round(100 * alignment_accuracy(preds, labels, variant="authors"), 1),
            "f1_tol1": round(100 * mean_f1(preds, [ep.boundaries for ep in eps], 1).f1, 1),
            "dropped_share": round(100 * (1 - kept), 1)}


def remedies(domain: str, checkpoint: Path, count: int, names: Sequence[str]) -> list[dict[str, Any]]:
    policy, _ = load_checkpoint(checkpoint)
    rows = []
    for name in names:
        eps = family_episodes(domain, FAMILIES[name], count)
        choice = choose_tolerance(eps)
        fold_t = choice.noise * noise_margin(int(eps[0].observations.shape[1]))
        row = {"domain": domain, "checkpoint": str(checkpoint), "family": name, "episodes": count,
               "still_tolerance_auto": round(choice.tolerance, 6), "fold_tolerance": round(fold_t, 6)}
        for arm, plan in arms(domain, choice.tolerance, fold_t).items():
            row[arm] = score(policy, domain, eps, plan)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def collate(out: Path, rows: Sequence[Path], arms_done: Sequence[Path], command: list[str]) -> Path:
    """Gather the JSON lines of ``memory`` / ``remedies`` runs and the rows of own-data arms
    (``lab.own_data``) into one results document."""
    doc: dict[str, Any] = {"study": "detours and still observations (docs/experiments.md §57)",
                           "command": command, "memory": [], "remedies": [], "arms": []}
    for path in rows:
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.strip():
                row = json.loads(line)
                doc["memory" if "score_detour" in row else "remedies"].append(row)
    for row in doc["remedies"]:  # a shipped checkpoint by its name, never by this machine's path
        if Path(row["checkpoint"]).is_absolute():
            row["checkpoint"] = f"shipped {row['domain']} checkpoint"
    doc["arms"] = [json.loads(p.read_text(encoding="utf-8")) for p in arms_done]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="study", required=True)
    m = sub.add_parser("memory", help="boundary score on detour steps (shipped Craft checkpoint)")
    r = sub.add_parser("remedies", help="each remedy against the DROID-style baseline")
    r.add_argument("--domain", choices=("craft", "dial"), default="craft")
    r.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    for p in (m, r):
        p.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped checkpoint")
        p.add_argument("--episodes", type=int, default=None, help="held-out episodes (Craft 150, Dial 60)")
    c = sub.add_parser("collate", help="gather JSON lines and arm rows into one results file")
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("rows", type=Path, nargs="+", help="JSON lines of memory / remedies")
    c.add_argument("--arm", type=Path, action="append", default=[], help="an own-data arm's row (JSON)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.study == "collate":
        print(collate(args.out, args.rows, args.arm, ["python", "-m", "lab.detours",
                                                      *(argv if argv is not None else sys.argv[1:])]))
        return 0
    if args.study == "memory":
        policy, _ = load_checkpoint(args.checkpoint or shipped_checkpoint("craft"))
        for name in ("human-like", "human-like without pauses", "pauses at boundaries"):
            eps = family_episodes("craft", FAMILIES[name], args.episodes or default_count("craft"))
            print(json.dumps({"family": name, **memory(policy, eps)}), flush=True)
        return 0
    remedies(args.domain, args.checkpoint or shipped_checkpoint(args.domain),
             args.episodes or default_count(args.domain), args.families)
    return 0


if __name__ == "__main__":
    sys.exit(main())
