"""Which online detector setting validation should pick: the grid search's previous rule (the largest
objective) against the one-standard-error rule, which a small validation set sways less
(docs/experiments.md §47).

For each arm of :mod:`lab.own_data` with a trained run, the validation and held-out test episodes'
teacher-forced scores are computed once (cached in ``<work>/selection/<arm>.npz``; the streaming
stepper gives the same ``p_hat`` to 1e-5), the whole default grid is evaluated on both, and each
rule's pick on validation is scored on test, beside the detector the run bundles (``detector.json``,
what ``ompn_node`` runs from the checkpoint: on Craft the duration decoder).  Nothing is trained.

    python -m lab.detector_selection --work runs/own_data            # results/detector_selection.json
    python -m lab.detector_selection --work runs/own_data ARM [ARM ...]  # printed only
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lab.own_data import arm_by_name, arm_configs, arm_data
from lab.report import write_study
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.factory import make_detector
from ompn_ros.detect.grid import GridRows, grid_on_labels, label_boundaries, scores_from_p_hats
from ompn_ros.detect.online import DetectorConfig, run_detector
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings
from ompn_ros.detect.tune import DEFAULT_OBJECTIVE, default_grid, delay_stats, pick_setting, pick_within_error
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.train.evaluation import teacher_forced_p_hat
from ompn_ros.train.trainer import train_val_episodes

Rows = list[dict[str, float]]


Validation = GridRows
"""The grid's metrics on a set of validation episodes, and one setting's per episode: the product's
:class:`~ompn_ros.detect.grid.GridRows`, as ``ompn_train``'s tuning sees them."""


def previous(val: Validation, objective: str) -> int:
    """The rule before docs/experiments.md §47: the largest objective, then the other metric."""
    return pick_setting(val.rows, objective)  # type: ignore[arg-type]


def one_standard_error(val: Validation, objective: str) -> int:
    """Settings within one standard error of the best objective are tied; the other metric decides."""
    return pick_within_error(val.rows, objective, val.per_episode, val.lengths)  # type: ignore[arg-type]


RULES: dict[str, Callable[[Validation, str], int]] = {"previous": previous, "one_se": one_standard_error}


def _arrays(p_hats: Sequence[np.ndarray], episodes: Sequence[Any], prefix: str) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for i, (p, ep) in enumerate(zip(p_hats, episodes, strict=True)):
        out[f"{prefix}_p{i}"] = np.asarray(p, dtype=np.float32)
        out[f"{prefix}_l{i}"] = np.asarray(ep.subtask, dtype=np.int64)
    return out


def arm_splits(arm_name: str, work: Path) -> tuple[list[Any], list[Any], list[Any], Any]:
    """(train, validation, test) episodes of the arm's run, as it split them, and its best checkpoint's
    policy (an OMPN, as the arm trains)."""
    arm = arm_by_name(arm_name)
    pool, test = arm_data(arm, work)
    _, cfg = arm_configs(arm, work, 1)
    train, val, _ = train_val_episodes(pool, cfg)
    return train, val, test, load_checkpoint(work / "runs" / arm.name / "best")[0]


def cached_scores(arm_name: str, work: Path) -> dict[str, list[np.ndarray]]:
    """``val_p``/``val_l``/``test_p``/``test_l``: per-episode ``p_hat`` and labels of the arm's best
    checkpoint on its validation and test episodes."""
    target = work / "selection" / f"{arm_name}.npz"
    if not target.is_file():
        _, val, test, policy = arm_splits(arm_name, work)
        doc = {**_arrays(teacher_forced_p_hat(policy, list(val))[0], val, "val"),
               **_arrays(teacher_forced_p_hat(policy, list(test))[0], test, "test")}
        target.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(target, **doc)  # type: ignore[arg-type]
    with np.load(target) as doc:
        out: dict[str, list[np.ndarray]] = {}
        for prefix in ("val", "test"):
            n = sum(1 for k in doc.files if k.startswith(f"{prefix}_p"))
            out[f"{prefix}_p"] = [doc[f"{prefix}_p{i}"] for i in range(n)]
            out[f"{prefix}_l"] = [doc[f"{prefix}_l{i}"] for i in range(n)]
    return out


_bounds = label_boundaries
"""Each episode's subtask ends from its labels (:func:`~ompn_ros.detect.grid.label_boundaries`)."""


def _grid_rows(p_hats: list[np.ndarray], labels: list[np.ndarray], grid: list[Any]) -> Rows:
    return validation(p_hats, labels, grid).rows


def validation(p_hats: list[np.ndarray], labels: list[np.ndarray], grid: list[Any]) -> Validation:
    """The grid on these episodes, as the tuning of ``ompn_train`` sees it
    (:func:`~ompn_ros.detect.grid.grid_on_labels`)."""
    return grid_on_labels(scores_from_p_hats(p_hats), labels, grid)


def online_figures(preds: Sequence[np.ndarray], detected_at: Sequence[Sequence[int]],
                   labels: Sequence[np.ndarray]) -> dict[str, float]:
    """F1@1, strict alignment, and the mean delay of inner boundaries and the share published only at
    the episode end (:func:`~ompn_ros.detect.tune.delay_stats`) of causal detections: per episode the
    boundary steps and the steps they were published at."""
    bounds = _bounds(list(labels))
    delays = delay_stats(preds, bounds, detected_at)
    return {"online_f1_1": mean_f1(preds, bounds, 1).f1,
            "online_align": alignment_accuracy(preds, list(labels), "strict"),
            "delay_mean": delays["delay_mean"], "at_end_share": delays["at_end_share"]}


def decoded(config: DetectorConfig, model: DurationModel | None, p_hats: Sequence[np.ndarray],
            labels: Sequence[np.ndarray]) -> dict[str, float]:
    """The causal detector ``config`` (``model`` for 'hsmm') on these episodes: :func:`online_figures`."""
    detector = make_detector(config, model)
    events = [run_detector(detector, s) for s in scores_from_p_hats(p_hats)]
    return online_figures([np.array([e.step for e in evs], dtype=np.int64) for evs in events],
                          [[e.detected_at for e in evs] for evs in events], labels)


def bundled_of(settings: DetectorSettings, data: dict[str, list[np.ndarray]]) -> dict[str, Any]:
    """The detector of ``settings`` on the test episodes of ``data`` (``test_p``, ``test_l``)."""
    got = decoded(settings.online, settings.duration_model, data["test_p"], data["test_l"])
    return {"config": settings.online.mode, "source": settings.source, "f1_1": got["online_f1_1"],
            "align": got["online_align"], "delay": got["delay_mean"]}


def bundled(arm_name: str, work: Path, data: dict[str, list[np.ndarray]]) -> dict[str, Any]:
    """The detector the arm's run bundles (``best/detector.json``, what ``ompn_node`` runs from the
    checkpoint) on the test episodes."""
    return bundled_of(load_detector_settings(work / "runs" / arm_name / "best"), data)


def study_arm(arm_name: str, work: Path) -> dict[str, Any]:
    """Per rule: the setting picked on validation and its validation and test F1@1 / alignment."""
    arm = arm_by_name(arm_name)
    data = cached_scores(arm_name, work)
    grid = default_grid()
    val = validation(data["val_p"], data["val_l"], grid)
    test = _grid_rows(data["test_p"], data["test_l"], grid)
    objective = DEFAULT_OBJECTIVE[arm.domain]
    out: dict[str, Any] = {"arm": arm_name, "domain": arm.domain, "objective": objective,
                           "val_episodes": len(data["val_p"]), "test_episodes": len(data["test_p"])}
    oracle = max(range(len(grid)), key=lambda g: test[g]["f1_tol1"] + test[g]["align_strict"])
    for name, rule in {**RULES, "test_oracle": lambda v, obj: oracle}.items():
        g = rule(val, objective)
        out[name] = {"config": repr(grid[g]), "val_f1_1": val.rows[g]["f1_tol1"],
                     "val_align": val.rows[g]["align_strict"],
                     "f1_1": test[g]["f1_tol1"], "align": test[g]["align_strict"],
                     "delay": test[g]["delay_mean"]}
    out["bundled"] = bundled(arm_name, work, data)
    return out


@dataclass(frozen=True)
class Family:
    """A set of arms scored together: the family the rule was checked on while it was chosen, or one
    kept out of that."""

    name: str
    role: str
    arms: tuple[str, ...]


def _seeded(pattern: str, seeds: Sequence[int]) -> tuple[str, ...]:
    return tuple(pattern.format(seed=s).replace("_seed0", "") for s in seeds)


FAMILIES = (
    Family("Dial, expert, complete seeds 0–4 and extrapolate 0–1", "seen while choosing the rule",
           _seeded("final_dial_complete_seed{seed}", range(5))
           + _seeded("final_dial_extrapolate_seed{seed}", range(2))),
    Family("Dial, human-like, complete and extrapolate, seeds 5–9", "kept out",
           _seeded("human_dial_complete_seed{seed}", range(5, 10))
           + _seeded("human_dial_extrapolate_seed{seed}", range(5, 10))),
    Family("Craft full, human-like, complete and blank best of 2, seeds 10–14", "kept out",
           _seeded("human_craft_full_complete_seed{seed}", range(10, 15))
           + _seeded("human_craft_full_blank_best2_seed{seed}", range(10, 15))),
    Family("Craft partial, human-like, complete and blank best of 2, seeds 10–14", "kept out",
           _seeded("human_craft_partial_complete_seed{seed}", range(10, 15))
           + _seeded("human_craft_partial_blank_best2_seed{seed}", range(10, 15))),
    Family("Craft partial, expert, complete, seeds 10–14", "kept out",
           _seeded("final_craft_partial_complete_seed{seed}", range(10, 15))),
)
RESULTS_FILE = "detector_selection.json"


def means(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per rule (and for the bundled detector), the mean test F1@1 and alignment over ``rows``
    (fractions)."""
    return {k: {"f1_1": float(np.mean([r[k]["f1_1"] for r in rows])),
                "align": float(np.mean([r[k]["align"] for r in rows]))}
            for k in [*RULES, "test_oracle", "bundled"]}


def family_row(family: Family, work: Path) -> dict[str, Any]:
    """The family's arms scored under every rule, their means, and how many picks the new rule changed."""
    rows = [study_arm(name, work) for name in family.arms]
    changed = sum(r["previous"]["config"] != r["one_se"]["config"] for r in rows)
    return {"family": family.name, "role": family.role, "runs": len(rows), "changed": changed,
            "means": means(rows), "arms": rows}


def write_results(work: Path, results: Path, command: Sequence[str]) -> Path:
    """``results/detector_selection.json`` over :data:`FAMILIES`, and the README regenerated."""
    meta = {"held_out": "test episodes of each bag set (20 %), never trained or tuned on; each rule picks "
                        "on the run's own validation episodes"}
    return write_study(results, RESULTS_FILE, command, meta, [family_row(f, work) for f in FAMILIES])


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.detector_selection [--work W] [--results R] [ARM ...]``: the study's families
    into ``R/detector_selection.json``, or the named arms printed."""
    parser = argparse.ArgumentParser(prog="python -m lab.detector_selection",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/own_data"))
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("arms", nargs="*", help="score these arms only (printed, nothing written)")
    args = parser.parse_args(argv)
    if not args.arms:
        given = list(argv if argv is not None else sys.argv[1:])
        command = ["python", "-m", "lab.detector_selection", *given]
        print(f"wrote {write_results(args.work, args.results, command)}")
        return 0
    rows = [study_arm(name, args.work) for name in args.arms]
    for row in rows:
        print(row["arm"], " ".join(f"{k}={100 * row[k]['f1_1']:.1f}/{100 * row[k]['align']:.1f}"
                                   for k in [*RULES, "test_oracle", "bundled"]))
    print("mean", " ".join(f"{k}={100 * v['f1_1']:.1f}/{100 * v['align']:.1f}"
                           for k, v in means(rows).items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
