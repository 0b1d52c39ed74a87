"""The reproduction's stages in order, each timed: collect bags, read them, hold out a test split,
train and score every setting and seed (and ensemble members), the extra tables, the result files,
optionally ship the primary checkpoint.  ``python -m lab.reproduce`` builds a :class:`ReproduceSpec` and calls
:func:`reproduce`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import torch

from lab import report
from lab.data import collect_bags, held_out_split, read_bags
from lab.ensembles import ensemble_scores, majority_min_length, member_ensemble_row
from lab.figures import save_figures
from lab.runs import BaseConfig, load_train_config, pin_fixed_length, run_setting
from lab.scoring import (
    DURATION_DELAYS,
    TRAINING_CELLS,
    Evaluation,
    aggregate,
    evaluate_policy,
)
from lab.ship import ship
from lab.spec import (
    ABLATIONS,
    DISTILL_WEIGHT,
    PRIMARY,
    SETTINGS,
    ReproduceError,
    ReproduceSpec,
    RunSpec,
)
from lab.sweeps import k_sweep, threshold_sweep
from ompn_ros.data.episode import Episode
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.errors import CheckpointError
from ompn_ros.train.threads import resolve_threads

T = TypeVar("T")
Split = tuple[list[Episode], list[Episode]]
ABLATION_CELLS = ("align_acc", "f1_tol1", "online_f1_tol1")
DISTILLED_CELLS = ("align", "f1_tol1", "constrained_align", "constrained_f1_tol1", "online_align",
                   "online_f1_tol1")


@dataclass
class Timer:
    """Wall time of every stage, printed as it ends."""

    stages: dict[str, float] = field(default_factory=dict)
    start: float = field(default_factory=time.perf_counter)

    def run(self, name: str, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        began = time.perf_counter()
        print(f"[{name}] ...", flush=True)
        result = fn(*args, **kwargs)
        elapsed = time.perf_counter() - began
        self.stages[name] = self.stages.get(name, 0.0) + elapsed
        print(f"[{name}] done in {elapsed:.1f} s", flush=True)
        return result


@dataclass
class State:
    """What the stages share: the spec, the base config, the splits, the tables written so far."""

    spec: ReproduceSpec
    base: BaseConfig
    timer: Timer = field(default_factory=Timer)
    data: dict[bool, Split] = field(default_factory=dict)
    results: dict[str, Any] = field(default_factory=dict)
    old_results: dict[str, Any] = field(default_factory=dict)
    figures: list[str] = field(default_factory=list)
    runs: dict[str, Evaluation] = field(default_factory=dict)
    students: dict[str, Evaluation] = field(default_factory=dict)  # seed 0's distilled run per setting
    extras: dict[str, report.ExtrasTable] = field(default_factory=dict)

    def run_spec(self, setting: str, seed: int, **fields: Any) -> RunSpec:
        s = self.spec
        return RunSpec(
            domain=s.domain,
            setting=SETTINGS[s.domain][setting],
            seed=seed,
            iterations=s.iterations,
            reuse=s.reevaluate,
            skip_trained=s.skip_trained,
            **fields,
        )

    def split_of(self, setting: str) -> Split:
        return self.data[SETTINGS[self.spec.domain][setting].partial]


def _show(row: dict[str, Any]) -> None:
    print("   " + ", ".join(f"{k} {v:.3f}" for k, v in row.items() if isinstance(v, float)))


def prepare(spec: ReproduceSpec) -> State:
    """Load the train config, set the torch threads, collect, read and split the bags."""
    base = load_train_config(spec.domain, spec.config)
    pin_fixed_length(base, spec.domain, spec.config is None)
    if spec.threads is not None:
        base["train"]["threads"] = spec.threads
    threads = resolve_threads(base["train"].get("threads", "auto"))
    if threads:
        torch.set_num_threads(threads)
    state = State(spec, base)
    previous = spec.results / f"{spec.domain}{report.MAIN_SUFFIX}"
    state.old_results = json.loads(previous.read_text()) if previous.is_file() else {}
    if spec.merge:
        state.results.update({k: v for k, v in state.old_results.items() if k not in spec.settings})
    for partial in sorted({SETTINGS[spec.domain][n].partial for n in spec.settings}):
        obs = "partial" if partial else "full"
        bags = state.timer.run(
            f"collect {spec.domain} {obs}",
            collect_bags,
            spec.domain,
            partial,
            spec.episodes,
            spec.data_seed,
            spec.work,
        )
        episodes = state.timer.run(f"read bags {obs}", read_bags, spec.domain, bags)
        state.data[partial] = held_out_split(episodes, spec.test_ratio, spec.data_seed)
        print(
            f"   {len(state.data[partial][0])} train+val episodes, {len(state.data[partial][1])} held-out "
            "test episodes"
        )
    spec.results.mkdir(parents=True, exist_ok=True)
    return state


def write(state: State) -> dict[str, Any]:
    """Write the result files (JSON and ``README.md``); returns the ``meta`` record."""
    spec = state.spec
    if spec.extras_only:
        return _add_extras(state)
    meta: dict[str, Any] = {
        "seeds": spec.seeds,
        "stages": dict(state.timer.stages),
        "total_seconds": time.perf_counter() - state.timer.start,
        "n_test": {("partial" if k else "full"): len(v[1]) for k, v in state.data.items()},
        "figures": state.figures,
        "command": list(spec.command),
    }
    extras_file = spec.results / f"{spec.domain}_extras.json"
    if spec.reevaluate and extras_file.is_file():
        # the tables come from the trained run: keep its command and stage times beside the re-evaluation
        trained = json.loads(extras_file.read_text()).get("meta", {})
        trained = trained.get("trained", trained)
        keep = ("command", "parallel_commands", "later_commands", "stages", "total_seconds")
        meta["trained"] = {k: trained[k] for k in keep if k in trained}
    report.write_results(spec.results, spec.domain, state.results, state.extras, meta)
    return meta


def _add_extras(state: State) -> dict[str, Any]:
    """``--extras-only``: the finished result files with this run's extra tables put in (a table of
    the same name keeps its other rows, the rows computed now replace theirs) and its command listed
    with the later ones; ``<domain>_lab.json`` is written back as it was."""
    spec = state.spec
    loaded = report.load(spec.results, spec.domain)
    if loaded is None:
        raise ReproduceError(f"--extras-only: no finished result files for {spec.domain} in {spec.results}")
    results, doc = loaded
    merged = dict(doc["extras"])
    for key, table in state.extras.items():
        old_rows = merged[key]["rows"] if key in merged else {}
        merged[key] = report.table(table["title"], {**old_rows, **table["rows"]})
    extras = {k: merged[k] for k in report.EXTRA_IDS if k in merged}
    meta = dict(doc["meta"])
    record = dict(meta.get("trained", meta))
    later = record.get("later_commands", [])
    if not later or later[-1] != list(spec.command):  # written after every setting: listed once
        record["later_commands"] = [*later, list(spec.command)]
    if "trained" in meta:
        meta["trained"] = record
    else:
        meta = record
    report.write_results(spec.results, spec.domain, results, extras, meta)
    return meta


def sweeps(state: State, setting: str, run: Evaluation, test: list[Episode]) -> None:
    """The appendix sweeps that apply to the domain: K for Craft, the threshold for Dial."""
    domain, wanted = state.spec.domain, state.spec.extras
    if "ksweep" in wanted and domain == "craft":
        state.extras["k_sweep"] = report.table(report.k_sweep_title(setting), k_sweep(run.p_hat, test))
    if "thresholds" in wanted and domain == "dial":
        state.extras["threshold_sweep"] = report.table(
            report.threshold_sweep_title(setting), threshold_sweep(run.p_hat, test)
        )


def evaluate_only(state: State) -> int:
    """``--evaluate CHECKPOINT``: score one checkpoint on the held-out split of the first setting."""
    spec = state.spec
    assert spec.evaluate is not None
    name = spec.settings[0]
    test = state.split_of(name)[1]
    try:
        policy = load_checkpoint(spec.evaluate)[0]
    except CheckpointError as exc:
        raise ReproduceError(
            f"--evaluate takes one checkpoint directory (ensembles are scored with --members): {exc}"
        ) from exc
    run = state.timer.run(f"evaluate {spec.evaluate}", evaluate_policy, spec.domain, policy, test)
    _show(run.row)
    # Re-evaluation refreshes the metric cells and keeps the training figures of an earlier run.
    state.results.setdefault(name, dict(state.old_results.get(name, {})))
    state.results[name].update(aggregate([run.row]))
    state.figures += save_figures(spec.domain, name, test, run, spec.results / "figures")
    sweeps(state, name, run, test)
    write(state)
    return 0


def _members(state: State, name: str, seed: int, run: Evaluation, count: int) -> dict[str, float]:
    """Train (or reload) the extra members of ``seed`` and score their ensemble with ``run``."""
    spec, timer = state.spec, state.timer
    stage = "re-evaluate" if spec.reevaluate else "train+eval"
    pool, test = state.split_of(name)
    members = [run] + [
        timer.run(
            f"{stage} {name} seed {seed} member {j}",
            run_setting,
            state.run_spec(name, seed, member=j),
            pool,
            test,
            state.base,
            spec.work,
        )
        for j in range(1, count)
    ]
    ensemble_dir = spec.work / "runs" / f"{name}_seed{seed}_ensemble{count}"
    scores = timer.run(
        f"ensemble {name} seed {seed}", member_ensemble_row, spec.domain, members, test, ensemble_dir
    )
    row = {"members": float(len(members)), **scores}
    print(f"   ensemble of {count}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()))
    return row


def _distilled(state: State, name: str, seed: int, count: int) -> dict[str, float]:
    """Train (or reload) one OMPN on ``seed``'s split that also learns the averaged ``p_hat`` of the
    seed's ``count`` ensemble members (``train.distill_from``, :mod:`ompn_ros.train.distill`), and
    score it like a single model: the :data:`DISTILLED_CELLS` and every online cell."""
    spec = state.spec
    stage = "re-evaluate" if spec.reevaluate else "train+eval"
    pool, test = state.split_of(name)
    runs = spec.work / "runs"
    teachers = [str(runs / state.run_spec(name, seed, member=j).name / "best") for j in range(count)]
    overrides = {"_train.distill_from": teachers, "_train.distill_weight": DISTILL_WEIGHT}
    student = state.run_spec(name, seed, tag=f"_distill{DISTILL_WEIGHT:g}", overrides=overrides)
    run = state.timer.run(
        f"{stage} {name} seed {seed} distilled", run_setting, student, pool, test, state.base, spec.work
    )
    if seed == 0:
        state.students[name] = run
    row = {k: run.row[k] for k in DISTILLED_CELLS if k in run.row}
    print("   distilled: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()))
    return row | {k: v for k, v in run.row.items() if k.startswith("online_")}  # for the online_lag table


@dataclass
class SettingTables:
    """What the settings loop adds to the extra tables (setting -> row)."""

    per_seed: dict[str, Any] = field(default_factory=dict)
    of_seeds: dict[str, Any] = field(default_factory=dict)
    distilled: dict[str, Any] = field(default_factory=dict)
    online_lag: dict[str, Any] = field(default_factory=dict)


def online_lag_rows(name: str, cells: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The ``online_lag`` rows of one setting: offline, the tuned threshold detector and the duration
    decoder within every scored mean delay (``online_hsmm_d<delay>_*``), each as align / F1@1 / delay /
    share of inner boundaries published at the episode's end (``at_end_share``)."""
    offline = {"delay_mean": None, "at_end_share": None}  # every boundary at the episode's end
    rows = {
        f"{name}: offline, paper's detector": {"align": cells["align"], "f1_tol1": cells["f1_tol1"],
                                               **offline},
        f"{name}: offline, constrained Top-K": {"align": cells["constrained_align"],
                                                "f1_tol1": cells["constrained_f1_tol1"], **offline},
    }
    online = {"online": "threshold"}
    online.update({f"online_hsmm_d{d:g}": f"hsmm, mean delay <= {d:g}" for d in DURATION_DELAYS})
    measures = (("align", "align_strict"), ("f1_tol1", "f1_tol1"), ("delay_mean", "delay_mean"),
                ("at_end_share", "at_end_share"))
    for prefix, label in online.items():
        if f"{prefix}_align_strict" in cells:
            rows[f"{name}: online, {label}"] = {k: cells.get(f"{prefix}_{m}") for k, m in measures}
    return rows


def train_setting(state: State, name: str, tables: SettingTables) -> None:
    """Every seed of one setting (and its ensemble members), aggregated into ``state.results``."""
    spec = state.spec
    stage = "re-evaluate" if spec.reevaluate else "train+eval"
    pool, test = state.split_of(name)
    want_ensemble = "ensemble" in spec.extras and spec.seeds >= 2
    rows, member_rows, distilled_rows, seed_p_hats = [], [], [], []
    for seed in range(spec.seeds):
        run = state.timer.run(
            f"{stage} {name} seed {seed}",
            run_setting,
            state.run_spec(name, seed),
            pool,
            test,
            state.base,
            spec.work,
        )
        _show(run.row)
        rows.append(run.row)
        seed_p_hats.append(run.p_hat)
        if seed == 0:
            state.runs[name] = run
        if spec.members.get(name, 1) > 1:
            member_rows.append(_members(state, name, seed, run, spec.members[name]))
            if "distill" in spec.extras:
                distilled_rows.append(_distilled(state, name, seed, spec.members[name]))
    state.results[name] = aggregate(rows)
    if member_rows:
        tables.per_seed[name] = aggregate(member_rows)
    if distilled_rows:
        students = aggregate(distilled_rows)
        tables.distilled[name] = {k: students[k] for k in DISTILLED_CELLS if k in students}
    if "online_lag" in spec.extras:
        tables.online_lag.update(online_lag_rows(name, state.results[name]))
        if distilled_rows:
            tables.online_lag.update(online_lag_rows(f"{name}, distilled", students))
    if want_ensemble:
        tables.of_seeds[name] = ensemble_scores(spec.domain, seed_p_hats, test, majority_min_length(rows))
    if spec.reevaluate:
        kept = state.old_results.get(name, {})
        state.results[name].update({k: kept[k] for k in TRAINING_CELLS if k in kept})
    if not spec.extras_only:
        state.figures += save_figures(spec.domain, name, test, state.runs[name], spec.results / "figures")
    write(state)


def ablations(state: State, primary: str) -> dict[str, dict[str, float]]:
    """The ablation table: seed 0 of ``primary`` trained with each ablation's overrides."""
    spec = state.spec
    pool, test = state.split_of(primary)
    rows = {}
    for name in spec.ablations:
        run_spec = state.run_spec(primary, 0, overrides=ABLATIONS[name], tag=f"_{name}")
        run = state.timer.run(
            f"{'re-evaluate ' if spec.reevaluate else ''}ablation {name}",
            run_setting,
            run_spec,
            pool,
            test,
            state.base,
            spec.work,
        )
        rows[name] = {k: run.row[k] for k in ABLATION_CELLS}
    return rows


def reproduce(spec: ReproduceSpec) -> int:
    """Run every stage of ``spec``; returns the exit code (0 when the result files were written)."""
    state = prepare(spec)
    if spec.evaluate is not None:
        return evaluate_only(state)
    if "ensemble" in spec.extras and spec.seeds < 2:
        print("   ensemble extra skipped: it averages several seeds and needs --seeds 2 or more")
    if "distill" in spec.extras and not any(spec.members.get(n, 1) > 1 for n in spec.settings):
        print("   distill extra skipped: its teachers are each seed's ensemble members (--members 2 or more)")
    tables = SettingTables()
    for name in spec.settings:
        train_setting(state, name, tables)
    primary = PRIMARY[spec.domain] if PRIMARY[spec.domain] in state.runs else spec.settings[0]
    sweeps(state, primary, state.runs[primary], state.split_of(primary)[1])
    if tables.per_seed:
        state.extras["ensembles_per_seed"] = report.table(
            report.ensembles_per_seed_title(spec.seeds), tables.per_seed
        )
    if tables.of_seeds:
        state.extras["ensemble_of_seeds"] = report.table(
            report.ensemble_of_seeds_title(spec.seeds), tables.of_seeds
        )
    if tables.distilled:
        state.extras["distilled"] = report.table(
            report.distilled_title(spec.seeds, DISTILL_WEIGHT), tables.distilled
        )
    if tables.online_lag:
        state.extras["online_lag"] = report.table(report.online_lag_title(spec.seeds), tables.online_lag)
    if "ablations" in spec.extras:
        state.extras["ablations"] = report.table(report.ablations_title(primary), ablations(state, primary))
    meta = write(state)
    if spec.ship:  # with the distill extra, seed 0's student (single-model cost, its ensemble's quality)
        distilled = primary in state.students
        run = state.students[primary] if distilled else state.runs[primary]
        provenance = {
            "command": list(spec.command),
            "setting": primary,
            "model": f"distilled from the seed's {spec.members[primary]} members" if distilled else "single",
            "seed": 0,
            "data_seed": spec.data_seed,
            "held_out_metrics": run.row,
            "results": str(spec.results),
        }
        assert run.checkpoint is not None
        print(
            f"   shipped {state.timer.run('ship checkpoint', ship, spec.domain, run.checkpoint, provenance)}"
        )
    print(
        f"total wall time {time.perf_counter() - state.timer.start:.1f} s; results in "
        f"{spec.results}/{report.README}"
    )
    print(
        json.dumps(
            {
                k: {m: round(v["mean"], 4) for m, v in row.items() if m in ("align_acc", "f1_tol1")}
                for k, row in state.results.items()
            }
        )
    )
    return 0 if meta else 1
