"""The shipped boundary head path, end to end, on episodes none of it was fitted on (docs/experiments.md
§52, §53).

For the shipped checkpoint of a domain, the product's own pieces fit a boundary head
(:func:`ompn_ros.train.boundary_head.fit_and_choose`, what ``ompn_train`` runs on labelled bags) on
generated expert episodes (seeds ``20000 +``) and choose its decoding on others (``30000 +``); the
bundled detector is the checkpoint's ``detector.json``.  Both are then replayed through the node's
``StreamingSegmenter`` (done step included, as live) on held-out expert episodes (``40000 +``) and
held-out human-like ones (``50000 +``, the default human-like demonstrator), and scored online.  The
per-run choice runs the head only where its validation alignment beats the bundled detector's.

``--work W ARM …`` scores runs of :mod:`lab.own_data` trained with ``train.boundary_head`` on, on the
run's own held-out test episodes: the detector ``ompn_train`` would bundle without the head
(:func:`ompn_ros.train.detector.choose_settings` again on the same validation episodes), the head
alone, the choice between them (what ``ompn_train`` bundled before mode 'head_hsmm'), the duration
decoder over the head with its threshold tuned on validation, and ``ompn_train``'s choice today.

    python -m lab.head_check --domain dial        # one JSON line per family
    python -m lab.head_check --work runs/own_data final_dial_complete_seed1   # one line per run
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import torch

from lab.boundary_head import robot_splits
from lab.detector_selection import arm_splits
from ompn_ros.app.replay import replay_all
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.choose import prefer, tune_head_duration
from ompn_ros.detect.defaults import DURATION_DELAY, DURATION_LAG
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import HEAD_DURATION_MODE, HEAD_MODE, DetectorConfig
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.detect.tune import score_online
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.train.boundary_head import choose_rule, fit_and_choose
from ompn_ros.train.detector import choose_settings
from ompn_ros.train.evaluation import teacher_forced_outputs
from sim_nodes.human import parse_human
from sim_nodes.registry import default_tasks, expert_episode

FIGURES = ("f1_tol1", "align", "delay_mean", "at_end_share", "false_alarms_per_episode")


def _episodes(domain: str, base: int, count: int, human: bool = False) -> list[Any]:
    tasks = default_tasks(domain)
    like = parse_human(domain) if human else None
    return [expert_episode(domain, base + i, task=tasks[i % len(tasks)], human=like) for i in range(count)]


def _online(stepper: Any, eps: list[Any], config: DetectorConfig, model: DurationModel | None,
            head: BoundaryHead | None = None) -> dict[str, float]:
    """The detector replayed through the node's segmenter (done step included) and scored online."""
    return score_online(replay_all(stepper, eps, config, model, head), eps, config, model, head)


def check(domain: str, n_train: int, n_val: int, n_test: int, seed: int) -> list[dict[str, Any]]:
    """Rows per held-out family: the bundled detector, the head and, with the checkpoint's duration
    model, mode 'head_hsmm' (its threshold tuned on the validation episodes), online on replays."""
    path = shipped_checkpoint(domain)
    policy, _ = load_checkpoint(path)
    bundled = load_detector_settings(path)
    train, val = _episodes(domain, 20000, n_train), _episodes(domain, 30000, n_val)
    val_outputs = teacher_forced_outputs(policy, val)  # type: ignore[arg-type]
    choice = fit_and_choose(teacher_forced_outputs(policy, train), train,  # type: ignore[arg-type]
                            val_outputs, val, seed)  # type: ignore[arg-type]
    model = bundled.duration_model
    both = None if model is None else tune_head_duration(model, choice.head, val_outputs, val,
                                                         DURATION_LAG, DURATION_DELAY)
    stepper = stepper_from_checkpoint(path)
    ref_val = _online(stepper, val, bundled.online, model)
    rows = []
    for family, eps in (("expert", _episodes(domain, 40000, n_test)),
                        ("human-like", _episodes(domain, 50000, n_test, human=True))):
        ref = _online(stepper, eps, bundled.online, model)
        got = _online(stepper, eps, choice.config, None, choice.head)
        if both is not None:
            both_got = _online(stepper, eps, both.config, model, choice.head)
            rows.append({"domain": domain, "family": family,
                         "head_hsmm": {k: both_got[k] for k in FIGURES},
                         "head_hsmm_rule": both.config.to_dict(),
                         "val_head_hsmm_align": both.metrics["align"]})
        rows.append({"domain": domain, "family": family, "test_episodes": len(eps),
                     "bundled": {k: ref[k] for k in FIGURES}, "bundled_mode": bundled.online.mode,
                     "head": {k: got[k] for k in FIGURES}, "head_rule": choice.config.to_dict(),
                     "head_peak": choice.head.peak, "val": {"bundled_align": ref_val["align"],
                                                            "head_align": choice.metrics["align"]},
                     "chosen": "head" if choice.metrics["align"] > ref_val["align"] else "bundled"})
    return rows


def check_run(arm_name: str, work: Path) -> dict[str, Any]:
    """One run of :mod:`lab.own_data`: its bundled detector, the one it would bundle without the
    head, and the head alone with the rule chosen with it, on the run's test episodes."""
    _, val, test, policy = arm_splits(arm_name, work)
    return {"arm": arm_name, **_check(work / "runs" / arm_name / "best", val, test, policy)}


def check_robot(flow: Path) -> dict[str, Any]:
    """:func:`check_run` for the robot profile's run of ``examples/own_robot.py --out FLOW``."""
    _, val, test, policy = robot_splits(flow)
    return {"arm": "robot_profile", **_check(flow / "model" / "best", val, test, policy)}


def _check(run: Path, val: list[Any], test: list[Any], policy: Any) -> dict[str, Any]:
    """The run's detectors on its test episodes: ``without_head`` (threshold or 'hsmm', chosen again on
    validation), ``head`` (its rule), ``previous`` (``ompn_train``'s choice before mode 'head_hsmm'),
    ``head_hsmm`` (its threshold tuned on validation within the delay budget; ``head_hsmm_any_delay``
    without it) and ``now`` (``ompn_train``'s choice today)."""
    bundled = load_detector_settings(run)
    if bundled.head is None:
        raise ValueError(f"{run}: no boundary head (trained with train.boundary_head off?)")
    head, outputs = bundled.head, teacher_forced_outputs(policy, val)
    p_hats = [x[:, :policy.config.n_slots + 1] for x in outputs]
    rule = head.rule or choose_rule(head, outputs, val).config
    before = choose_settings(p_hats, val, action_type=policy.config.action_type, use_labels=True,
                             what="without the head")
    figures = dict(before.metrics)
    head_figures = {k: bundled.metrics[f"head_val_{k}"] for k in ("align", "f1_tol1", "delay_mean")}
    previous = prefer(before.online, figures, HEAD_MODE, rule, head_figures)
    model = before.duration_model
    detectors = {"without_head": before.online, "head": rule, "previous": previous}
    if model is not None:
        tuned = tune_head_duration(model, head, outputs, val, DURATION_LAG, DURATION_DELAY)
        detectors["head_hsmm"] = tuned.config
        detectors["head_hsmm_any_delay"] = tune_head_duration(  # the delay budget's cost
            model, head, outputs, val, DURATION_LAG, None).config
        detectors["now"] = prefer(previous, figures, HEAD_DURATION_MODE, tuned.config, tuned.metrics)
    stepper = stepper_from_checkpoint(run)
    scored = {name: _online(stepper, test, config, model, head) for name, config in detectors.items()}
    return {"test_episodes": len(test), "bundled_mode": bundled.online.mode,
            "modes": {name: config.mode for name, config in detectors.items()}, "head_rule": rule.to_dict(),
            "head_hsmm_rule": detectors.get("head_hsmm", rule).to_dict(), "head_peak": head.peak,
            "val": {k: v for k, v in figures.items() if k.endswith(("_val_align", "_val_f1_tol1"))},
            **{name: {k: got[k] for k in FIGURES} for name, got in scored.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lab.head_check", description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", choices=("craft", "dial"))
    parser.add_argument("--work", type=Path, help="the work directory of lab.own_data (with ARMs)")
    parser.add_argument("--robot", type=Path, help="an `examples/own_robot.py --out` directory")
    parser.add_argument("arms", nargs="*")
    parser.add_argument("--train", type=int, default=160)
    parser.add_argument("--val", type=int, default=40)
    parser.add_argument("--test", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.work is not None or args.robot is not None:
        for arm in args.arms:
            print(json.dumps(check_run(arm, args.work)), flush=True)
        if args.robot is not None:
            print(json.dumps(check_robot(args.robot)), flush=True)
        return 0
    if args.domain is None:
        parser.error("give --domain, or --work with runs")
    for row in check(args.domain, args.train, args.val, args.test, args.seed):
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
