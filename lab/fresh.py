"""A reproduction's runs scored on newly generated demonstrations that no choice ever saw.

The reproduction holds out one test split per data seed, and the decisions of docs/experiments.md
were read on it.  This module collects a new set of demonstrations with another data seed and
scores every run of one setting on it exactly as ``python -m lab.reproduce`` scores its test split: offline
detectors, and the online detectors tuned on the run's own validation episodes (the threshold
detector, and the duration decoder within each mean delay of
:data:`~lab.scoring.DURATION_DELAYS`), docs/experiments.md §44.

    python -m lab.fresh --work runs/online_lag/work_partial_nosketch \\
        --setting partial_nosketch --seeds 5 --episodes 200 --data-seed 4242 [--distilled] \\
        --out runs/fresh/partial_distilled.json

Cost: collecting ``episodes`` per task once (reused when already there), then per run one
evaluation as in the reproduction: O(Σ T) replays plus the decoder's calibration on validation.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lab.data import collect_bags, read_bags
from lab.pipeline import State, online_lag_rows, prepare
from lab.runs import build_configs
from lab.scoring import aggregate, evaluate_policy
from lab.spec import DISTILL_WEIGHT, SETTINGS, ReproduceError, ReproduceSpec
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.errors import CheckpointError
from ompn_ros.train.trainer import train_val_episodes


def score_run(state: State, setting: str, seed: int, distilled: bool, fresh: list[Any]) -> dict[str, float]:
    """The row of ``seed``'s run (or its distilled student) on ``fresh``, its detectors tuned on the
    run's own validation episodes (the seed's split, as in :func:`~lab.runs.run_setting`)."""
    spec = state.run_spec(setting, seed, tag=f"_distill{DISTILL_WEIGHT:g}" if distilled else "")
    run_dir = state.spec.work / "runs" / spec.name
    _, train_cfg = build_configs(spec, state.base, run_dir)
    _, val, n_val = train_val_episodes(state.split_of(setting)[0], train_cfg)
    try:
        policy = load_checkpoint(run_dir / "best")[0]
    except CheckpointError as exc:
        raise ReproduceError(f"run {spec.name}: {exc}") from exc
    # without a validation split the trainer validated on training episodes: never tune on those
    return evaluate_policy(state.spec.domain, policy, fresh, val if n_val else ()).row


def fresh_rows(work: Path, setting: str, seeds: int, episodes: int, data_seed: int, distilled: bool,
               reproduced: tuple[int | None, int] = (None, 0)) -> dict[str, dict[str, Any]]:
    """The ``online_lag`` rows of ``setting``'s runs on ``episodes`` new demonstrations per task;
    ``reproduced``: the reproduction's ``--episodes`` (None: the default) and ``--data-seed``."""
    spec = ReproduceSpec.build("craft", settings=setting, seeds=seeds, work=work, episodes=reproduced[0],
                               data_seed=reproduced[1], results=work / "fresh_results", reevaluate=True)
    state = prepare(spec)
    partial = SETTINGS["craft"][setting].partial
    bags = collect_bags("craft", partial, episodes, data_seed, work / "fresh" / f"seed{data_seed}")
    fresh = read_bags("craft", bags)
    rows = [score_run(state, setting, seed, distilled, fresh) for seed in range(seeds)]
    label = f"{setting}, distilled" if distilled else setting
    return online_lag_rows(f"{label} ({len(fresh)} new episodes, data seed {data_seed})", aggregate(rows))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lab.fresh", description=__doc__)
    parser.add_argument("--work", type=Path, required=True, help="the reproduction's work directory")
    parser.add_argument("--setting", choices=sorted(SETTINGS["craft"]), default="partial_nosketch")
    parser.add_argument("--seeds", type=int, default=5, help="runs of seeds 0 … N-1")
    parser.add_argument("--episodes", type=int, default=200, help="new demonstrations per task")
    parser.add_argument("--data-seed", type=int, default=4242, help="seed of the new demonstrations")
    parser.add_argument("--distilled", action="store_true", help="the seeds' distilled students")
    parser.add_argument("--out", type=Path, required=True, help="JSON file of the rows")
    parser.add_argument("--reproduced", type=int, nargs=2, default=None, metavar=("EPISODES", "DATA_SEED"),
                        help="the reproduction's --episodes and --data-seed (default: its defaults)")
    args = parser.parse_args(argv)
    if args.data_seed == (args.reproduced or (None, 0))[1]:
        parser.error("--data-seed must differ from the reproduction's: its episodes are not new")
    try:
        rows = fresh_rows(args.work, args.setting, args.seeds, args.episodes, args.data_seed, args.distilled,
                          tuple(args.reproduced) if args.reproduced else (None, 0))
    except (ReproduceError, OSError) as exc:
        print(f"fresh: error: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1) + "\n")
    for label, row in rows.items():
        cells = [f"{k} {v['mean']:.3f}" for k, v in row.items() if isinstance(v, dict)]
        print(f"{label}: {', '.join(cells)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
