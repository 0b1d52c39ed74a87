"""The reproduction through the product: ``make reproduce-craft`` / ``make reproduce-dial``.

``python -m lab.reproduce_product craft`` (``dial`` likewise) runs, for every setting and training
seed, the commands a user would type, and nothing of the lab's own tuning:

1. ``ompn_collect`` the training demonstrations (seed 0) and the held-out test demonstrations (seeds
   from :data:`lab.ship_product.TEST_SEED`, never trained or tuned on), the amounts of
   :data:`lab.ship_product.EPISODES` (the paper's 500 per Craft task, 1 400 Dial demonstrations, 80 / 20);
2. ``ompn_train --bags TRAIN --config config/train_<domain>.yaml`` with the seed, the setting's sketch
   and the paper's protocol of a fixed number of updates (:data:`lab.spec.REPRODUCTION_ITERATIONS`,
   ``train.patience=0``); everything else is ``ompn_train``'s default: ``still_tolerance: auto``, the
   restart rule, the boundary head and the detector it chooses and bundles as ``best/detector.json``;
3. ``ompn_segment --bag TEST --checkpoint RUN/best``: the node's replay with that bundled detector
   (online) and the paper's offline detector on the same ``p_hat`` (Top-K for Craft, the automatic
   threshold for Dial, with K the true number of subtasks).

``results/<domain>.json`` holds the mean, std and count over seeds of every setting run
(:data:`PAPER_DETECTOR` figures under their plain names, the bundled detector's under ``online_``) and a
``provenance`` record: the package version, this command, every product command and which seeds and
settings it holds.  Where it differs from the paper: the test demonstrations are a separate collection
(seeds from 70 000) rather than a random 20 % of one, and the online figures are the node's, which the
paper does not have.

Each step is skipped when its output is already complete (``--fresh`` redoes all), so an interrupted
reproduction continues where it stopped.  The lab's in-process study (ensembles, distillation, sweeps,
ablations, detectors tuned by the lab) is ``python -m lab.reproduce``; its tables are
``results/<domain>_lab.json`` and ``results/<domain>_extras.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import ompn_ros
from lab import report
from lab.ship_product import DOMAIN_ARGS, EPISODES, TEST_SEED, run_step
from lab.spec import REPRODUCTION_ITERATIONS, SETTINGS, Setting

PIPELINE = "lab.reproduce_product"
"""The name the result files' ``provenance`` carries."""
PAPER_DETECTOR = {"craft": "offline_topk", "dial": "offline_auto"}
"""The paper's offline detector of each domain, as ``ompn_segment``'s ``metrics.json`` names it."""
ONLINE = "online"
"""``ompn_segment``'s figures of the node's replay with the checkpoint's own ``detector.json``."""
OFFLINE_KEYS = ("align", "align_strict", "f1_tol0", "f1_tol1")
ONLINE_KEYS = ("align", "align_strict", "f1_tol0", "f1_tol1", "delay_mean", "false_alarms_per_episode",
               "at_end_share")
TRAIN_KEYS = ("train_seconds", "best_iteration", "iterations", "restarts")


def observation(setting: Setting) -> str:
    return "partial" if setting.partial else "full"


def bag_dir(work: Path, domain: str, setting: Setting, split: str) -> Path:
    suffix = "_partial" if setting.partial else ""
    return work / "bags" / f"{domain}{suffix}_{split}"


def run_name(domain: str, setting: str, seed: int) -> str:
    return f"{domain}_{setting}_seed{seed}"


def collect_commands(domain: str, setting: Setting, work: Path) -> dict[str, list[str]]:
    """``ompn_collect`` of the training (seed 0) and held-out test (:data:`TEST_SEED`) bags."""
    partial = ["--partial"] if setting.partial else []
    return {
        f"collect_{observation(setting)}_{split}": [
            "ompn_collect", "--domain", domain, *DOMAIN_ARGS[domain], *partial, *EPISODES[domain][split],
            "--seed", str(seed), "--out", str(bag_dir(work, domain, setting, split)), "--quiet",
        ]
        for split, seed in (("train", 0), ("test", TEST_SEED))
    }


def run_commands(domain: str, name: str, seed: int, work: Path, iterations: int) -> dict[str, list[str]]:
    """``ompn_train`` and ``ompn_segment`` of one setting and seed; segment scores ``RUN/best`` with the
    detector the training bundled there (no ``--detector-config``: the checkpoint's ``detector.json``)."""
    setting = SETTINGS[domain][name]
    run = work / "runs" / run_name(domain, name, seed)
    sketch = ["--set", "model.sketch_mode=sum"] if setting.sketch else []
    # one thread: training is then deterministic for a seed, and two runs share two cores
    train = ["ompn_train", "--bags", str(bag_dir(work, domain, setting, "train")), "--config",
             f"config/train_{domain}.yaml", "--set", "train.threads=1", "--set",
             f"train.iterations={iterations}", "--set", "train.patience=0", "--set", f"train.seed={seed}",
             *sketch, "--out", str(run), "--quiet"]
    segment = ["ompn_segment", "--bag", str(bag_dir(work, domain, setting, "test")), "--checkpoint",
               str(run / "best"), "--domain", domain, "--out",
               str(work / "segment" / run_name(domain, name, seed)), "--plot-episodes", "0"]
    return {"train": train, "segment": segment}


def seed_row(domain: str, metrics: dict[str, Any], summary: dict[str, Any]) -> dict[str, float]:
    """One seed's result cells: the paper's offline detector under the plain names, the bundled online
    detector under ``online_``, the training figures of ``summary.json``."""
    paper, online = metrics[PAPER_DETECTOR[domain]], metrics[ONLINE]
    row = {k: float(paper[k]) for k in OFFLINE_KEYS}
    row.update({f"online_{k}": float(online[k]) for k in ONLINE_KEYS})
    row.update({k: float(summary[k]) for k in TRAIN_KEYS if k in summary})
    return row


def aggregate(rows: Sequence[dict[str, float]]) -> dict[str, report.Cell]:
    """Per cell, mean and (population) std over the seeds and their count."""
    out: dict[str, report.Cell] = {}
    for key in rows[0]:
        values = np.asarray([r[key] for r in rows], dtype=np.float64)
        out[key] = {"mean": float(values.mean()), "std": float(values.std()), "n": len(rows)}
    return out


def score_run(domain: str, steps: dict[str, list[str]]) -> tuple[dict[str, float], dict[str, Any]]:
    """The row of one finished run and what it ran with (the bundled detector's mode and source)."""
    run = Path(steps["train"][steps["train"].index("--out") + 1])
    scored = Path(steps["segment"][steps["segment"].index("--out") + 1])
    metrics = json.loads((scored / "metrics.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    detector = json.loads((run / "best" / "detector.json").read_text())
    online = detector.get("online", {})
    record = {"run": str(run), "detector_mode": online.get("mode"), "detector_source": detector.get("source"),
              "commands": {k: " ".join(v) for k, v in steps.items()}}
    return seed_row(domain, metrics, summary), record


def reproduce_setting(
    domain: str, name: str, args: argparse.Namespace
) -> tuple[dict[str, report.Cell], dict[str, Any]]:
    """Collect (once per observation kind), train and score every seed of one setting."""
    setting = SETTINGS[domain][name]
    for step, argv in collect_commands(domain, setting, args.work).items():
        run_step(step, argv, args.fresh)
    rows, runs = [], {}
    for seed in range(args.seeds):
        steps = run_commands(domain, name, seed, args.work, args.iterations)
        for step, argv in steps.items():
            run_step(f"{step} {name} seed {seed}", argv, args.fresh)
        row, runs[str(seed)] = score_run(domain, steps)
        rows.append(row)
        print(f"   {name} seed {seed}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
    return aggregate(rows), runs


def provenance(domain: str, args: argparse.Namespace, runs: dict[str, Any]) -> dict[str, Any]:
    """What the result file came from: version, command, every product command, seeds and settings."""
    collect = {}
    for name in args.settings:
        collect.update(collect_commands(domain, SETTINGS[domain][name], args.work))
    record: dict[str, Any] = {
        "pipeline": PIPELINE,
        "version": ompn_ros.__version__,
        "reproduce": ["python", "-m", PIPELINE, *args.argv],
        "settings": list(args.settings),
        "seeds": list(range(args.seeds)),
        "iterations": args.iterations,
        "collect": {k: " ".join(v) for k, v in collect.items()},
        "held_out": f"a separate collection, seeds from {TEST_SEED}, never trained or tuned on",
        "offline_detector": f"the paper's: {PAPER_DETECTOR[domain]} of ompn_segment's metrics.json",
        "online_detector": "each checkpoint's own detector.json, chosen and bundled by ompn_train",
        "runs": runs,
    }
    if args.note:
        record["note"] = args.note
    return record


def write_results(results: Path, domain: str, table: dict[str, Any], record: dict[str, Any]) -> Path:
    """``results/<domain>.json``: ``{"provenance": ..., "settings": {setting: {cell: {mean, std, n}}}}``."""
    results.mkdir(parents=True, exist_ok=True)
    target = results / f"{domain}.json"
    doc = {"provenance": record, "settings": table}
    target.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return target


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=f"python -m {PIPELINE}", description=__doc__.split("\n\n")[0])
    parser.add_argument("domain", choices=sorted(SETTINGS))
    parser.add_argument("--settings", default="", help="comma list (empty: every setting of the domain)")
    parser.add_argument("--seeds", type=int, default=5,
                        help="training seeds 0..N-1 per setting (5, as the paper)")
    parser.add_argument("--work", type=Path, default=Path("runs/reproduce"))
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--fresh", action="store_true", help="redo every step")
    parser.add_argument("--note", default="", help="a remark kept in the provenance (e.g. a reused run)")
    return parser


def _without_note(argv: list[str]) -> list[str]:
    """The command line to record: a ``--note`` is kept in the provenance, not in the command."""
    out, skip = [], False
    for arg in argv:
        if skip or arg.startswith("--note="):
            skip = False
            continue
        skip = arg == "--note"
        if not skip:
            out.append(arg)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    raw = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(raw)
    args.argv = _without_note(raw)
    known = SETTINGS[args.domain]
    args.settings = [s for s in args.settings.split(",") if s] or list(known)
    unknown = [s for s in args.settings if s not in known]
    if unknown:
        print(f"error: --settings: {', '.join(unknown)} unknown; known: {', '.join(known)}", file=sys.stderr)
        return 2
    if args.seeds < 1:
        print(f"error: --seeds {args.seeds}: give 1 or more", file=sys.stderr)
        return 2
    args.iterations = REPRODUCTION_ITERATIONS[args.domain]
    table, runs = {}, {}
    for name in args.settings:
        table[name], runs[name] = reproduce_setting(args.domain, name, args)
    target = write_results(args.results, args.domain, table, provenance(args.domain, args, runs))
    print(f"wrote {target}; {report.write_readme(args.results)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
