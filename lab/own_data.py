"""Studies on our own Craft and Dial bags for users without labels or with robot-style bags.

Three studies, each a set of *arms* (one training run, or one existing checkpoint, scored on the
held-out test episodes of the reproduction's split, :func:`lab.data.held_out_split`):

* ``labels``: labels hidden from training and calibration (``train.labels: none``); the same
  checkpoint scored with the detector tuned on the validation labels and with the label-free one
  (:func:`ompn_ros.detect.calibrate.calibrate_label_free`, the detector ``ompn_train`` bundles
  without labels).
* ``final_observation``: every episode's final observation removed from the training bags
  (:mod:`lab.strip`), read with ``final_observation: drop_last_step``,
  ``duplicate``, ``blank`` or ``extrapolate``, against the complete bags.  Test episodes stay complete.
* ``length``: early stopping (``train.patience``) against the fixed length of the reproduction.
* ``demonstrator``: the same protocols on bags of the human-like demonstrator (docs/craft.md §2.6,
  docs/dial.md §3.9), a family no default was tuned on: complete bags, and bags without the final
  observation read with the domain's preset.

Labels are only used for scoring, except by the label-tuned detector.  ``run`` trains and scores
one arm into ``<work>/arms/<arm>.json``; ``rescore`` scores its run again with today's scoring,
keeping how it was trained; ``collate`` gathers them into ``results/own_data.json``
(rendered by :mod:`lab.report`); ``gather`` writes the rows of some arms and their means over seeds
into a results file of their own.  Cost per arm: one training run plus one replay
of the validation and test episodes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from lab.runs import build_configs, load_train_config, pin_fixed_length
from lab.scoring import evaluate_policy
from lab.spec import (
    DEFAULT_EPISODES,
    DEFAULT_TEST_RATIO,
    REPRODUCTION_ITERATIONS,
    SETTINGS,
    ReproduceError,
    RunSpec,
)
from ompn_ros.app.replay import compare_detectors
from ompn_ros.data.cache import load_arrays
from ompn_ros.data.cuts import choose_tolerance
from ompn_ros.data.episode import Episode
from ompn_ros.data.errors import BagError
from ompn_ros.data.reader import FinalObservation, ReaderSpec
from ompn_ros.detect.choose import calibrate_without_labels
from ompn_ros.detect.defaults import LABEL_FREE_REFERENCE, LABEL_FREE_REFERENCE_MIN_LENGTH
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.load import build_stepper
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainStateError
from ompn_ros.train.precision import cpu_model
from ompn_ros.train.restart import read_attempt, read_record
from ompn_ros.train.trainer import train, train_val_episodes

from .data import HUMAN_VARIANTS, IDLE_TOLERANCE, collapse_idle, collect_bags, held_out_split
from .replayed import replayed_figures
from .report import write_readme
from .report_own import OWN_DATA
from .strip import strip_bags

Study = Literal["labels", "final_observation", "length", "demonstrator"]
Demonstrator = Literal["expert", "human", "human_nopauses", "human_nodetours", "human_boundaries"]
Bags = Literal["complete", "drop_last_step", "duplicate", "blank", "extrapolate"]
Length = Literal["patience", "fixed"]
DATA_SEED = 0
"""Seed of the reproduction's held-out split (``python -m lab.reproduce --data-seed`` default)."""


@dataclass(frozen=True)
class Arm:
    """One arm of a study: what is trained on which bags, and how long."""

    name: str
    study: Study
    domain: str
    partial: bool = False
    labels: Literal["auto", "none"] = "auto"
    length: Length = "patience"
    bags: Bags = "complete"
    seed: int = 0
    candidates: int = 1
    """``train.candidates``: initialisations trained, the best by validation kept (experiments §43)."""
    last_of: str = ""
    """Not trained: the ``last/`` checkpoint of this other arm's run is scored (no selection)."""
    demonstrator: Demonstrator = "expert"
    restart: bool = True
    """False: the restart rule off (``train.restart_at: 0``), to see what a restarted run would have
    become."""
    idle: bool = True
    """False: the training and validation episodes lose their idle steps (:func:`lab.data.collapse_idle`,
    docs/experiments.md §54); the test episodes keep them."""
    still: float | Literal["auto"] = 0.0
    """``model.still_tolerance``: the product's rule for still observations (:mod:`ompn_ros.data.cuts.still`),
    applied by ``ompn_train`` and every replay; the run is scored through the node's replay.  ``'auto'``:
    chosen from the training pool as ``ompn_train`` chooses it
    (:func:`ompn_ros.data.cuts.choose_tolerance`)."""

    @property
    def data(self) -> str:
        """The bag set: ``<domain>_<full|partial>[_<demonstrator>]`` (none for the expert)."""
        suffix = "" if self.demonstrator == "expert" else f"_{self.demonstrator}"
        return f"{self.domain}_{'partial' if self.partial else 'full'}{suffix}"


STILL_TOLERANCE = IDLE_TOLERANCE
"""``model.still_tolerance`` of the still arms: Craft's observation elements are 0/1 and its human-like
sensor noise stays far below 0.2 (the tolerance of the §54 measurement, not tuned on any score)."""


def _label_arms() -> list[Arm]:
    """The labels study: labels hidden from training and calibration."""
    return [
        Arm("labels_craft_full", "labels", "craft", labels="none"),
        Arm("labels_craft_partial", "labels", "craft", partial=True, labels="none"),
        Arm("labels_dial", "labels", "dial", labels="none"),
        Arm("labels_dial_last", "labels", "dial", labels="none", last_of="labels_dial"),
        Arm("labels_craft_full_seed1", "labels", "craft", labels="none", seed=1),
        Arm("labels_dial_seed1", "labels", "dial", labels="none", seed=1),
    ]


def _length_and_final_arms() -> list[Arm]:
    """Per domain, seed 0: early stopping against the fixed length, and each final-observation
    handling against complete bags."""
    arms: list[Arm] = []
    for domain in ("craft", "dial"):
        tag = "craft_full" if domain == "craft" else "dial"
        arms += [
            Arm(f"length_{tag}_patience", "length", domain, length="patience"),
            Arm(f"length_{tag}_fixed", "length", domain, length="fixed"),
            Arm(f"final_{tag}_complete", "final_observation", domain, length="fixed"),
            Arm(
                f"final_{tag}_drop_last_step",
                "final_observation",
                domain,
                length="fixed",
                bags="drop_last_step",
            ),
            Arm(f"final_{tag}_duplicate", "final_observation", domain, length="fixed", bags="duplicate"),
            Arm(f"final_{tag}_blank", "final_observation", domain, length="fixed", bags="blank"),
        ]
    return arms


def _final_seed_arms() -> list[Arm]:
    """The seeded arms of the final-observation study."""
    arms: list[Arm] = []
    # Seeded pairs of the final-observation study (docs/experiments.md §42): Craft's blank and Dial's
    # extrapolated row T against complete bags (seed 0's Craft pair is defined above); Craft seeds
    # 10-19 and Dial seeds 5-9 are §43's held-out seeds
    for tag, domain, bags, seeds in (("craft_full", "craft", "blank", range(1, 20)),
                                     ("dial", "dial", "extrapolate", range(10))):
        for seed in seeds:
            suffix = f"_seed{seed}" if seed else ""
            if seed:
                arms.append(Arm(f"final_{tag}_complete{suffix}", "final_observation", domain, length="fixed",
                                seed=seed))
            arms.append(Arm(f"final_{tag}_{bags}{suffix}", "final_observation", domain, length="fixed",
                            bags=bags, seed=seed))  # type: ignore[arg-type]
    # Dial's copied row T on the expert seeds of the extrapolate choice: the second option of
    # final_observation: auto (docs/experiments.md §48; seed 0's arm is defined above)
    for seed in range(1, 5):
        arms.append(Arm(f"final_dial_duplicate_seed{seed}", "final_observation", "dial", length="fixed",
                        bags="duplicate", seed=seed))
    # §43: the better of two initialisations by validation alignment, on the held-out seeds
    for seed in range(10, 20):
        for bags in ("complete", "blank"):
            arms.append(Arm(f"final_craft_full_{bags}_best2_seed{seed}", "final_observation", "craft",
                            length="fixed", bags=bags, seed=seed, candidates=2))  # type: ignore[arg-type]
    # expert demonstrations on partial observation: the reference of the human-like partial arms
    for seed in range(10, 15):
        arms.append(Arm(f"final_craft_partial_complete_seed{seed}", "final_observation", "craft",
                        partial=True, length="fixed", seed=seed))
    return arms


def _human_craft_arms() -> list[Arm]:
    """Human-like Craft demonstrations (a family kept out of every tuning), the held-out seeds of §43:
    complete bags, Craft's blank row T (best of 2), and the restart rule off."""
    arms: list[Arm] = []
    for seed in range(10, 15):
        arms += [
            Arm(f"human_craft_full_complete_seed{seed}", "demonstrator", "craft", length="fixed",
                seed=seed, demonstrator="human"),
            Arm(f"human_craft_full_blank_best2_seed{seed}", "demonstrator", "craft", length="fixed",
                bags="blank", seed=seed, candidates=2, demonstrator="human"),
        ]
    # the same on partial observation: Craft's blank, best of 2 was tuned on full observation
    for seed in range(10, 15):
        arms += [
            Arm(f"human_craft_partial_complete_seed{seed}", "demonstrator", "craft", partial=True,
                length="fixed", seed=seed, demonstrator="human"),
            Arm(f"human_craft_partial_blank_best2_seed{seed}", "demonstrator", "craft", partial=True,
                length="fixed", bags="blank", seed=seed, candidates=2, demonstrator="human"),
        ]
    for seed in range(10, 15):  # the rule abandoned the first initialisation of every partial complete arm
        arms.append(Arm(f"human_craft_partial_complete_norestart_seed{seed}", "demonstrator", "craft",
                        partial=True, length="fixed", seed=seed, demonstrator="human", restart=False))
    for seed in (11, 12):  # the complete arms whose first initialisation the restart rule abandoned
        arms.append(Arm(f"human_craft_full_complete_norestart_seed{seed}", "demonstrator", "craft",
                        length="fixed", seed=seed, demonstrator="human", restart=False))
    return arms


def _human_craft_variant_arms() -> list[Arm]:
    """The human-like Craft demonstrator without one perturbation, without idle steps, and with the
    still rule (§54, §55, §57)."""
    arms: list[Arm] = []
    # the human-like demonstrator without one perturbation: which one costs the training (§54)
    for seed in range(10, 15):
        for variant in ("nopauses", "nodetours"):
            arms.append(Arm(f"human_craft_full_{variant}_seed{seed}", "demonstrator", "craft", length="fixed",
                            seed=seed, demonstrator=f"human_{variant}"))  # type: ignore[arg-type]
        for partial in (False, True):
            obs = "partial" if partial else "full"
            arms.append(Arm(f"human_craft_{obs}_noidle_seed{seed}", "demonstrator", "craft", partial=partial,
                            length="fixed", seed=seed, demonstrator="human", idle=False))
            # the same through the product's model.still_tolerance (§55)
            arms.append(Arm(f"human_craft_{obs}_still_seed{seed}", "demonstrator", "craft", partial=partial,
                            length="fixed", seed=seed, demonstrator="human", still=STILL_TOLERANCE))
            # still_tolerance: auto, on the defaults and on pauses at subtask changes (§57)
            for demonstrator in ("human", "human_boundaries"):
                tag = "auto" if demonstrator == "human" else "boundaries_auto"
                arms.append(Arm(f"human_craft_{obs}_{tag}_seed{seed}", "demonstrator", "craft",
                                partial=partial, length="fixed", seed=seed,
                                demonstrator=demonstrator, still="auto"))  # type: ignore[arg-type]
    return arms


def _human_dial_arms() -> list[Arm]:
    """Human-like Dial demonstrations, seeds 5-9: complete bags, the still rule on pauses at subtask
    changes, and the row T guesses."""
    arms: list[Arm] = []
    for seed in range(5, 10):
        arms += [
            Arm(f"human_dial_boundaries_auto_seed{seed}", "demonstrator", "dial", length="fixed", seed=seed,
                demonstrator="human_boundaries", still="auto"),
            Arm(f"human_dial_complete_seed{seed}", "demonstrator", "dial", length="fixed", seed=seed,
                demonstrator="human"),
            Arm(f"human_dial_extrapolate_seed{seed}", "demonstrator", "dial", length="fixed",
                bags="extrapolate", seed=seed, demonstrator="human"),
            # extrapolating a noisy human-like row T: does a copy of the last observation do better?
            Arm(f"human_dial_duplicate_seed{seed}", "demonstrator", "dial", length="fixed",
                bags="duplicate", seed=seed, demonstrator="human"),
        ]
    return arms


def _arms() -> dict[str, Arm]:
    """Every arm of the studies by name, in the order the steps above define them."""
    steps = (_label_arms, _length_and_final_arms, _final_seed_arms, _human_craft_arms,
             _human_craft_variant_arms, _human_dial_arms)
    return {a.name: a for step in steps for a in step()}


ARMS = _arms()


def arm_by_name(name: str) -> Arm:
    if name not in ARMS:
        raise ReproduceError(f"unknown arm {name!r}; known: {sorted(ARMS)}")
    return ARMS[name]


def read_episodes(
    bags: Path, domain: str, cache: Path, final_observation: FinalObservation | None = None,
    lenient: bool = False,
) -> list[Episode]:
    """Episodes of ``bags`` through the cached reader of ``ompn_train`` (cache under ``cache``).

    With ``final_observation`` (stripped bags) or ``lenient`` (human-like bags, whose dropped
    observation messages leave a command without its partner) the domain's reader spec is made
    lenient, as a robot's reader config is: an end marker counting one step more than
    ``drop_last_step`` keeps is then a note of the read report instead of an error."""
    spec = ReaderSpec.for_domain(domain)
    if final_observation is not None:
        spec = replace(spec, final_observation=final_observation, strict=False)
    elif lenient:
        spec = replace(spec, strict=False)
    episodes = load_arrays(bags, spec=spec, cache_dir=cache).episodes()
    if not episodes:
        raise ReproduceError(f"no episodes in {bags}")
    return episodes


def _key(ep: Episode) -> tuple[str, int]:
    return (ep.task, int(ep.seed))


def arm_data(arm: Arm, work: Path) -> tuple[list[Episode], list[Episode]]:
    """(train pool, test): the reproduction's split of the complete bags; for stripped arms the
    pool's episodes are taken, in the same order, from the stripped copy read with the arm's option."""
    human = arm.demonstrator != "expert"
    complete = read_episodes(work / "bags" / arm.data, arm.domain, work / "cache", lenient=human)
    pool, test = held_out_split(complete, DEFAULT_TEST_RATIO, DATA_SEED)
    if arm.bags == "complete":
        return pool, test
    stripped = read_episodes(work / "stripped" / arm.data, arm.domain, work / "cache", arm.bags)
    by_key = {_key(ep): ep for ep in stripped}
    if len(by_key) != len(stripped) or any(_key(ep) not in by_key for ep in pool):
        raise ReproduceError(
            f"the stripped bags of {arm.data} do not hold the same episodes as the complete ones"
        )
    return [by_key[_key(ep)] for ep in pool], test


def arm_configs(arm: Arm, work: Path, threads: int) -> tuple[Any, TrainConfig]:
    """The shipped train config with the arm's labels, length (early stopping as shipped, or the
    reproduction's fixed length) and seed."""
    base = load_train_config(arm.domain, None)
    base["train"]["threads"] = threads
    base["train"]["labels"] = arm.labels
    if arm.length == "fixed":
        pin_fixed_length(base, arm.domain, shipped=True)
    setting = SETTINGS[arm.domain][
        "partial_nosketch" if arm.partial else ("full_nosketch" if arm.domain == "craft" else "nosketch")
    ]
    base["train"]["candidates"] = arm.candidates
    if not arm.restart:
        base["train"]["restart_at"] = 0
    spec = RunSpec(domain=arm.domain, setting=setting, seed=arm.seed)
    model, train = build_configs(spec, base, work / "runs" / arm.name)
    fixed = arm.still if isinstance(arm.still, float) else 0.0  # 'auto' is chosen from the pool (train_arm)
    return (replace(model, still_tolerance=fixed) if fixed else model), train


def train_arm(
    arm: Arm, pool: list[Episode], work: Path, threads: int, resume_from: Path | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Train the arm (``<work>/runs/<arm>/``); the run's length, best iteration and wall time.

    ``resume_from``: a finished shorter run of the same data, model and seed (e.g. the fixed-length
    run) whose resumable state this run continues; training is deterministic, so this equals an
    uninterrupted run whenever early stopping would not have stopped before that run's end.
    ``resume``: continue what ``<work>/runs/<arm>/`` holds (e.g. a candidate copied in from the single
    run of the same seed, which is candidate 0)."""
    model_cfg, train_cfg = arm_configs(arm, work, threads)
    chosen: dict[str, Any] = {}
    if arm.still == "auto":
        choice = choose_tolerance(pool)
        model_cfg = replace(model_cfg, still_tolerance=choice.tolerance)
        chosen = {"still_auto": choice.as_dict()}
        print(f"   {arm.name}: {choice.summary()}", file=sys.stderr)
    out = work / "runs" / arm.name
    earlier = 0.0
    if resume:
        train_cfg = replace(train_cfg, resume=True)
    if resume_from is not None:
        if out.exists():
            raise ReproduceError(f"{out} exists; remove it to resume from {resume_from}")
        shutil.copytree(resume_from, out)
        train_cfg = replace(train_cfg, resume=True)
        earlier = _train_seconds(resume_from)
    torch.set_num_threads(max(1, threads))
    began = time.perf_counter()
    result = train(pool, model_cfg, train_cfg)
    return {
        "iterations": result.iterations,
        "best_iteration": result.best_iteration,
        "stopped_early": bool(result.stopped_early),
        "selection": result.selection,
        "train_seconds": time.perf_counter() - began + earlier,
        "patience": train_cfg.patience,
        "iteration_cap": train_cfg.iterations,
        **({"resumed_from": resume_from.name} if resume_from is not None else {}),
        **({"candidates": result.candidates} if result.candidates else {}),
        **chosen,
    }


def _train_seconds(run_dir: Path) -> float:
    """Wall time of a finished run: ``train_seconds`` of its arm file or ``summary.json`` (0: unknown)."""
    for doc in (run_dir.parent.parent / "arms" / f"{run_dir.name}.json", run_dir / "summary.json"):
        if doc.is_file():
            value = json.loads(doc.read_text()).get("train_seconds")
            if isinstance(value, int | float):
                return float(value)
    return 0.0


def restarts_of(run_dir: Path) -> int:
    """How many times the restart rule started ``run_dir``'s run, or its candidates, again (the
    attempts their run directories record; 0 without any)."""
    return read_attempt(run_dir) + sum(read_attempt(c) for c in sorted(run_dir.glob("candidates/*")))


def abandoned_of(run_dir: Path) -> int:
    """How many of ``run_dir``'s run and candidates were trained under the restart rule of before it
    kept the better attempt (docs/design.md#restart-rule): their record names no kept attempt, the
    first initialisation was abandoned at ``restart_at``."""
    records = [read_record(d) for d in [run_dir, *sorted(run_dir.glob("candidates/*"))]]
    return sum(1 for r in records if r and "kept" not in r)


def score_arm(
    arm: Arm, checkpoint: Path, pool: list[Episode], test: list[Episode], cfg: TrainConfig
) -> dict[str, Any]:
    """Held-out scores of ``checkpoint``: offline (the paper's detector), online with the detector
    tuned on the validation labels and online with the label-free calibrated one."""
    policy = load_checkpoint(checkpoint)[0]
    if arm.still:  # the teacher-forced scoring below would step the still rows: the product's replay
        got = replayed_figures(checkpoint, arm.domain, test)
        return {"offline_f1_1": got["offline_f1_1"] / 100, "offline_align": got["offline_align"] / 100,
                "online_f1_1": got["online_f1_1"] / 100, "online_align": got["online_align"] / 100,
                "online_detector": got["online_mode"], "test_episodes": len(test)}
    _, val, _ = train_val_episodes(pool, cfg)
    run = evaluate_policy(arm.domain, policy, test, val)
    p_hats = run.val_p_hat  # teacher-forced, as ompn_train calibrates
    action_type = "discrete" if arm.domain == "craft" else "continuous"
    free = calibrate_without_labels(p_hats, val, action_type)
    scores = compare_detectors(build_stepper(policy), test, {"label_free": free.config}, replays=run.replays)
    tuned = run.tuning.config if run.tuning is not None else None
    return {
        "offline_f1_1": run.row["f1_tol1"],
        "offline_align": run.row["align_acc"],
        "online_f1_1": run.row["online_f1_tol1"],
        "online_align": run.row["online_align"],
        "label_free_online_f1_1": float(scores["label_free"]["f1_tol1"]),
        "label_free_online_align": float(scores["label_free"]["align"]),
        "label_tuned_detector": None if tuned is None else repr(tuned),
        "label_free_detector": repr(free.config),
        "label_free_reference": f"{LABEL_FREE_REFERENCE} (min_length {LABEL_FREE_REFERENCE_MIN_LENGTH})",
        "train_episodes": len(pool) - len(val),
        "val_episodes": len(val),
        "test_episodes": len(test),
    }


def run_arm(
    arm: Arm, work: Path, threads: int = 1, checkpoint: Path | None = None, resume_from: Path | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Train (or, with ``checkpoint``, reuse a run trained with the same config) and score one arm;
    writes ``<work>/arms/<arm>.json`` and returns its row."""
    pool, test = arm_data(arm, work)
    if not arm.idle:
        pool = [collapse_idle(ep)[0] for ep in pool]
    _, cfg = arm_configs(arm, work, threads)
    info: dict[str, Any]
    if arm.last_of and checkpoint is None:
        checkpoint = work / "runs" / arm.last_of / "last"
    if checkpoint is None:
        info = train_arm(arm, pool, work, threads, resume_from, resume)
        checkpoint = work / "runs" / arm.name / "best"
    else:
        reached = int(load_checkpoint(checkpoint)[1].get("iteration", -1))
        info = {
            "iterations": cfg.iterations if cfg.patience == 0 else reached,
            "best_iteration": reached,
            "stopped_early": False,
            "selection": "none (last checkpoint)" if arm.last_of else cfg.selection,
            "train_seconds": None,
            "patience": cfg.patience,
            "iteration_cap": cfg.iterations,
            "checkpoint": checkpoint.name,
        }
    row: dict[str, Any] = {
        "arm": arm.name,
        "study": arm.study,
        "domain": arm.domain,
        "observation": "partial" if arm.partial else "full",
        "labels": arm.labels,
        "length": arm.length,
        "bags": arm.bags,
        "seed": arm.seed,
        "demonstrator": arm.demonstrator,
        **({} if arm.restart else {"restart": False}),
        **({} if arm.idle else {"idle_steps": "collapsed in training"}),
        **({"candidates_trained": arm.candidates} if arm.candidates > 1 else {}),
        **info,
    }
    row.update(score_arm(arm, checkpoint, pool, test, cfg))
    row["restarts"] = restarts_of(work / "runs" / (arm.last_of or arm.name))
    out = work / "arms" / f"{arm.name}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(row, indent=1) + "\n")
    return row


TRAINING_FIELDS = ("iterations", "best_iteration", "stopped_early", "selection", "train_seconds", "patience",
                   "iteration_cap", "checkpoint")
"""What a rescored arm keeps of its row: how it was trained, not how it scores."""


def rescore_arm(arm: Arm, work: Path) -> dict[str, Any]:
    """Score ``arm``'s trained checkpoint again with today's scoring (e.g. a newer detector rule) and
    keep the training fields of its row (``<work>/arms/<arm>.json``, which must exist)."""
    path = work / "arms" / f"{arm.name}.json"
    if not path.is_file():
        raise ReproduceError(f"{path} does not exist: run the arm before rescoring it")
    before = json.loads(path.read_text())
    run_dir = work / "runs" / (arm.last_of or arm.name)
    row = run_arm(arm, work, checkpoint=run_dir / ("last" if arm.last_of else "best"))
    row.update({k: before[k] for k in TRAINING_FIELDS if k in before})
    path.write_text(json.dumps(row, indent=1) + "\n")
    return row


def strip_arm_bags(work: Path, data: str) -> Path:
    """The stripped copy ``<work>/stripped/<data>`` of ``<work>/bags/<data>`` (made once)."""
    out = work / "stripped" / data
    if not out.exists():
        tmp = out.parent / f".{data}.partial"
        if tmp.exists():
            raise ReproduceError(f"a previous stripping of {data} was interrupted: remove {tmp}")
        strip_bags(work / "bags" / data, tmp)
        tmp.rename(out)
    return out


def collate(work: Path, results: Path, command: list[str], notes: Sequence[str] = ()) -> Path:
    """Gather ``<work>/arms/*.json`` into ``results/own_data.json`` (rows in :data:`ARMS` order) and
    regenerate ``results/README.md``.  The fixed-length run of a domain doubles as the complete-bags
    arm of the final-observation study when that arm was not run separately."""
    found = {p.stem: json.loads(p.read_text()) for p in sorted((work / "arms").glob("*.json"))}
    for name, arm in ARMS.items():
        twin = f"length_{name.removeprefix('final_').removesuffix('_complete')}_fixed"
        if (
            arm.study == "final_observation"
            and arm.bags == "complete"
            and name not in found
            and twin in found
        ):
            found[name] = {**found[twin], "arm": name, "study": arm.study}
    rows = [found[name] for name in ARMS if name in found]
    for row in rows:  # arms scored before their rows recorded restarts: read the run directories
        run_dir = work / "runs" / row["arm"]
        if "restarts" not in row and run_dir.is_dir():
            row["restarts"] = restarts_of(run_dir)
        row.pop("restart_abandoned", None)
        if run_dir.is_dir() and (abandoned := abandoned_of(run_dir)):
            row["restart_abandoned"] = abandoned
    if not rows:
        raise ReproduceError(f"no arm results under {work / 'arms'}")
    episodes: dict[str, dict[str, int]] = {}
    for row in rows:  # one entry per bag set, and one more per other number of episodes read from it
        human = "" if row.get("demonstrator", "expert") == "expert" else f"_{row['demonstrator']}"
        data = f"{row['domain']}_{row['observation']}{human}"
        split = {"train": row["train_episodes"], "val": row["val_episodes"], "test": row["test_episodes"]}
        first = episodes.setdefault(data, split)
        if first != split:
            episodes.setdefault(f"{data} ({sum(split.values())} episodes)", split)
    meta = {
        "command": command,
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "cpu": cpu_model(),
        "threads": 1,
        "seeds": sorted({int(r["seed"]) for r in rows}),
        "data_seed": DATA_SEED,
        "test_ratio": DEFAULT_TEST_RATIO,
        "episodes": episodes,
        "fixed_iterations": REPRODUCTION_ITERATIONS,
        "notes": list(notes),
    }
    results.mkdir(parents=True, exist_ok=True)
    target = results / OWN_DATA
    target.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    write_readme(results)
    return target


SCORES = ("offline_align", "offline_f1_1", "online_align", "online_f1_1")
"""The held-out figures every arm's row has (fractions), averaged over seeds by :func:`gather`."""


def gather(work: Path, arms: Sequence[str], out: Path, command: list[str]) -> Path:
    """Write the rows of ``arms`` (``<work>/arms/<arm>.json``, each must exist) to ``out``, with the
    mean and standard deviation over seeds of :data:`SCORES` per *family* (the arm's name without its
    ``_seed<k>``), in % ."""
    missing = [a for a in arms if not (work / "arms" / f"{a}.json").is_file()]
    if missing:
        raise ReproduceError(f"no result of {', '.join(missing)} under {work / 'arms'} (run them first)")
    rows = [json.loads((work / "arms" / f"{a}.json").read_text()) for a in arms]
    families: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        families.setdefault(row["arm"].rsplit("_seed", 1)[0], []).append(row)
    def spread(values: list[float]) -> dict[str, float]:
        return {"mean": round(100 * float(np.mean(values)), 1), "std": round(100 * float(np.std(values)), 1)}

    means = {family: {"seeds": [int(r["seed"]) for r in members],
                      **{key: spread([float(r[key]) for r in members]) for key in SCORES}}
             for family, members in families.items()}
    meta = {"command": command, "date": time.strftime("%Y-%m-%d", time.gmtime()), "cpu": cpu_model(),
            "threads": 1, "data_seed": DATA_SEED, "test_ratio": DEFAULT_TEST_RATIO}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meta": meta, "means": means, "rows": rows}, indent=1) + "\n")
    return out


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`: one sub-command per step of the study."""
    parser = argparse.ArgumentParser(
        prog="python -m lab.own_data", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--work",
        type=Path,
        default=Path("runs/own_data"),
        help="work directory: bags/<domain>_<obs>/, stripped/, cache/, runs/, arms/",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "collect", help="collect the seeded demonstrations of a bag set (reproduction defaults)"
    )
    p.add_argument("data", choices=[f"{d}{h}" for d in ("craft_full", "craft_partial", "dial_full")
                                    for h in ("", *(f"_{v}" for v in HUMAN_VARIANTS))])
    p.add_argument(
        "--episodes", type=int, default=0, help="per task for Craft, in total for Dial (0 = default)"
    )
    p = sub.add_parser("strip", help="write <work>/stripped/<data>: the bags without final observations")
    p.add_argument("data", choices=["craft_full", "craft_partial", "dial_full", "craft_full_human",
                                    "craft_partial_human", "dial_full_human"])
    p = sub.add_parser("run", help="train and score one arm into <work>/arms/<arm>.json")
    p.add_argument("arm", choices=sorted(ARMS))
    p.add_argument("--threads", type=int, default=1)
    p.add_argument(
        "--checkpoint", type=Path, help="score this checkpoint (trained with the arm's config) instead"
    )
    p.add_argument("--resume-from", type=Path, help="continue this finished shorter run of the same config")
    p.add_argument("--resume", action="store_true", help="continue what the arm's run directory holds")
    p = sub.add_parser("rescore", help="score the arm's trained run again (today's detector rule), keeping "
                       "the training fields of <work>/arms/<arm>.json")
    p.add_argument("arm", choices=sorted(ARMS))
    p = sub.add_parser("collate", help="write results/own_data.json and results/README.md")
    p.add_argument("--results", type=Path, default=Path("results"))
    p.add_argument("--note", action="append", default=[], help="a sentence printed under the tables")
    p = sub.add_parser("gather", help="write the rows of some arms, and their means over seeds, to one file")
    p.add_argument("arms", nargs="+", choices=sorted(ARMS), metavar="ARM")
    p.add_argument("--out", type=Path, required=True)
    return parser


def _run_command(args: argparse.Namespace, argv: list[str] | None) -> Path | str:
    """Run the sub-command ``args.command``; return what it prints."""
    if args.command == "collect":
        domain, obs, *human = args.data.split("_", 2)
        episodes = args.episodes or DEFAULT_EPISODES[domain]
        demonstrator = human[0] if human else "expert"
        return collect_bags(domain, obs == "partial", episodes, DATA_SEED, args.work, demonstrator)
    if args.command == "strip":
        return strip_arm_bags(args.work, args.data)
    if args.command == "run":
        row = run_arm(
            arm_by_name(args.arm), args.work, args.threads, args.checkpoint, args.resume_from, args.resume
        )
        return json.dumps(row, indent=1)
    if args.command == "rescore":
        return json.dumps(rescore_arm(arm_by_name(args.arm), args.work), indent=1)
    if args.command == "gather":
        command = ["python", "-m", "lab.own_data", *(argv if argv is not None else sys.argv[1:])]
        return str(gather(args.work, args.arms, args.out, command))
    given = list(argv if argv is not None else sys.argv[1:])
    kept = [a for k, a in enumerate(given) if a != "--note" and (k == 0 or given[k - 1] != "--note")]
    command = ["python", "-m", "lab.own_data", *kept]  # notes are stored apart
    return collate(args.work, args.results, command, args.note)


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.own_data {collect,strip,run,rescore,collate,gather} ...`` (see ``--help``)."""
    args = _parser().parse_args(argv)
    try:
        print(_run_command(args, argv))
    except (ReproduceError, BagError, TrainStateError, OSError) as exc:
        print(f"own_data: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
