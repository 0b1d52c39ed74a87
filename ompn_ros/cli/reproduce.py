"""``ompn_reproduce``: from an empty directory to the paper's tables, through rosbag2 files.

Stages (each timed): collect seeded expert demonstrations into bags (``ompn_collect``), read the
bags back into episodes (the same reader users run on their own bags), hold out a test split by
seed, train OMPN with the shipped config for every setting and seed, evaluate on the held-out
episodes only (offline Top-K / automatic threshold, and the online causal detector through the
same ``StreamingSegmenter`` the node runs), then write ``results/<domain>.json`` (shape
``{setting: {metric: {"mean", "std", "n"}}}``, metrics as fractions), ``results/<domain>.md`` and
figures (π over time with true and detected boundaries, like the paper's Figures 4–5 and 9).

Extras, each a separate table: the K sweep (Craft), the threshold sweep (Dial), and the ablations
plus both memory-update variants.  ``--ship`` copies the seed-0 checkpoint of the primary setting
into the package (``ompn_ros/checkpoints/``) together with its provenance.

Examples::

    ompn_reproduce craft                       # Craft, the 4 settings, shipped seed count
    ompn_reproduce craft --settings full_nosketch --seeds 1 --extras none   # the ≤ 10 min path
    ompn_reproduce dial --ship
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros import layout
from ompn_ros.data.episode import Episode
from ompn_ros.paths import config_file

LOG = logging.getLogger("ompn_ros.reproduce")
CRAFT_TASKS = ("makebed", "makeaxe", "makeshears")


@dataclass(frozen=True)
class Setting:
    """One row of the paper's Table 1."""

    name: str
    partial: bool = False
    sketch: bool = False


SETTINGS: dict[str, dict[str, Setting]] = {
    "craft": {
        s.name: s
        for s in (
            Setting("full_nosketch"),
            Setting("full_sketch", sketch=True),
            Setting("partial_nosketch", partial=True),
            Setting("partial_sketch", partial=True, sketch=True),
        )
    },
    "dial": {s.name: s for s in (Setting("nosketch"), Setting("sketch", sketch=True))},
}
PRIMARY = {"craft": "full_nosketch", "dial": "nosketch"}
EXTRAS = ("ksweep", "thresholds", "ablations", "ensemble")
ABLATIONS = {
    "memory_paper": {"memory_update": "paper"},
    "memory_code": {"memory_update": "code"},
    "no_bottom_up": {"no_bottom_up": True},
    "no_top_down": {"no_top_down": True},
    "no_bottom_up_recurrence": {"no_bottom_up_recurrence": True},
    "no_done_loss": {"_train.no_done_loss": True},
}
DEFAULT_EPISODES = {"craft": 500, "dial": 1400}  # Craft: per task; Dial: in total
DEFAULT_TEST_RATIO = 0.2


class ReproduceError(RuntimeError):
    """A stage of the reproduction cannot run (names the stage and the cause)."""


@dataclass
class Timer:
    """Wall time of every stage, printed as it ends."""

    stages: dict[str, float] = field(default_factory=dict)

    def run(self, name: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        print(f"[{name}] ...", flush=True)
        result = fn(*args, **kwargs)
        elapsed = time.perf_counter() - start
        self.stages[name] = self.stages.get(name, 0.0) + elapsed
        print(f"[{name}] done in {elapsed:.1f} s", flush=True)
        return result


# --- data ----------------------------------------------------------------------------------------


def collect_bags(domain: str, partial: bool, episodes: int, seed: int, work: Path) -> Path:
    """Seeded demonstrations into ``work/bags/<domain>_<obs>/`` (reused when already complete)."""
    from ompn_ros.cli.collect import MANIFEST, collect

    out = work / "bags" / f"{domain}_{'partial' if partial else 'full'}"
    tasks = list(CRAFT_TASKS) if domain == "craft" else ["dial"]
    total = episodes * len(tasks) if domain == "craft" else episodes
    manifest_file = out / MANIFEST
    if manifest_file.is_file():
        manifest = json.loads(manifest_file.read_text())
        if manifest.get("totals", {}).get("episodes") == total and manifest["settings"]["seed"] == seed:
            print(f"   reusing {out} ({total} episodes)")
            return out
    collect(out, domain=domain, tasks=tasks, episodes=total, seed=seed, partial=partial,
            split_every=max(1, total // 4), overwrite=out.exists(), progress=sys.stderr.isatty(),
            command=["ompn_collect", "--domain", domain, "--task", ",".join(tasks), "--episodes", str(total),
                     "--seed", str(seed), *(["--partial"] if partial else [])])
    return out


def read_bags(domain: str, bags: Path) -> list[Episode]:
    """Episodes from the bags, through the cached reader that ``ompn_train`` uses."""
    from ompn_ros.data.bag_reader import ReaderSpec
    from ompn_ros.data.cache import load_arrays

    arrays = load_arrays(bags, spec=ReaderSpec.for_domain(domain), cache_dir=bags.parent / ".cache")
    episodes = arrays.episodes()
    if not episodes:
        raise ReproduceError(f"read stage: no episodes in {bags}")
    return episodes


def held_out_split(
    episodes: Sequence[Episode], ratio: float, seed: int
) -> tuple[list[Episode], list[Episode]]:
    """Seeded split, stratified by task: (train pool, test).  Test episodes are never trained on."""
    rng = np.random.default_rng([seed, 0x7E57])
    train: list[Episode] = []
    test: list[Episode] = []
    for task in sorted({ep.task for ep in episodes}):
        group = [ep for ep in episodes if ep.task == task]
        order = rng.permutation(len(group))
        n_test = max(1, round(ratio * len(group)))
        test.extend(group[i] for i in order[:n_test])
        train.extend(group[i] for i in order[n_test:])
    overlap = {(ep.task, ep.seed) for ep in train} & {(ep.task, ep.seed) for ep in test}
    if overlap:
        raise ReproduceError(f"split stage: {len(overlap)} episodes are in both train and test")
    return train, test


# --- training and evaluation ---------------------------------------------------------------------


def load_train_config(domain: str, path: Path | None) -> dict[str, dict[str, Any]]:
    from ompn_ros.cli.train import load_config

    return load_config(str(path or config_file(f"train_{domain}.yaml")))


def build_configs(domain: str, base: dict[str, dict[str, Any]], setting: Setting, seed: int,
                  iterations: int | None, out_dir: Path, overrides: dict[str, Any] | None = None):
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.train.trainer import TrainConfig

    dom = layout.DOMAINS[domain]
    model = {**base["model"], "obs_dim": dom.obs_dim, "action_type": dom.action_type,
             "action_dim": dom.action_dim}
    train = {**base["train"], "seed": seed, "out_dir": str(out_dir), "progress": False}
    if setting.sketch:
        model["sketch_mode"] = "sum"
        model["sketch_vocab"] = dom.sketch_vocab
    else:
        model["sketch_mode"], model["sketch_vocab"] = "none", 0
    if iterations is not None:
        train["iterations"] = iterations
    for key, value in (overrides or {}).items():
        if key.startswith("_train."):
            train[key.removeprefix("_train.")] = value
        else:
            model[key] = value
    return OMPNConfig.from_dict(model), TrainConfig.from_dict(train)


def offline_metrics(policy: Any, episodes: Sequence[Episode], min_length: int) -> dict[str, Any]:
    """Teacher-forced loss, ``p_hat`` and the offline detectors' metrics on ``episodes``."""
    from ompn_ros.train.trainer import evaluate

    return evaluate(policy, episodes, keep_p_hat=True, min_length=min_length)


def online_metrics(
    policy: Any, test: Sequence[Episode], domain: str, val: Sequence[Episode] = (), stepper: Any = None
) -> tuple[dict[str, float], list[Any], Any]:
    """The causal detector replayed through ``StreamingSegmenter`` (as live) on ``test``.

    Two detector settings are scored on the same replays: the shipped one of ``domain``
    (``online_shipped_*``; it was tuned on the shipped checkpoint) and one tuned for this checkpoint
    by ``ompn_segment --tune``'s grid search (the domain's default objective) on ``val``, the run's
    validation episodes, never the test ones (``online_*``).  Without ``val`` the shipped setting is
    reported under both names.  ``stepper`` replaces ``policy``'s own stepper (an ensemble's).
    Returns ``(metrics, replays with the primary setting, tuning record or None)``.
    """
    from ompn_ros.cli.segment import (
        DEFAULT_OBJECTIVE,
        choose_detector,
        compare_detectors,
        load_detector_yaml,
        replay_all,
    )
    from ompn_ros.model.factory import build_stepper

    shipped = load_detector_yaml(config_file(f"ompn_node_{domain}.yaml"))
    stream = stepper if stepper is not None else build_stepper(policy)
    configs = {"shipped": shipped}
    tuning = None
    if val:
        tuned, _, on_val = choose_detector(stream, list(val), objective=DEFAULT_OBJECTIVE[domain])
        configs["tuned"] = tuned
        tuning = {"config": tuned, "measured_on_val": on_val, "n_val": len(val)}
    replays = replay_all(stream, test, configs.get("tuned", shipped))
    scores = compare_detectors(stream, test, configs, replays=replays)
    row = {f"online_shipped_{k}": v for k, v in scores["shipped"].items()}
    row.update({f"online_{k}": v for k, v in scores["tuned" if tuning else "shipped"].items()})
    return row, replays, tuning


TRAINING_CELLS = ("train_seconds", "frames_per_second")
"""Result cells that only training produces (kept from the previous results by --reevaluate)."""
METRIC_KEYS = ("align", "align_strict", "f1_tol0", "f1_tol1", "precision_tol1", "recall_tol1")


def run_setting(domain: str, setting: Setting, seed: int, train_pool: list[Episode], test: list[Episode],
                base: dict[str, dict[str, Any]], iterations: int | None, work: Path,
                overrides: dict[str, Any] | None = None, tag: str = "",
                reuse: bool = False, skip_trained: bool = False, member: int = 0) -> dict[str, Any]:
    """Train one (setting, seed), or with ``reuse`` load its existing ``best/`` checkpoint, and
    evaluate it on the held-out test episodes (the detectors are tuned on the run's validation split).

    ``member`` > 0 trains an extra ensemble member of the seed (``<setting>_seed<seed>_m<member>``):
    training seed ``seed + MEMBER_SEED_STRIDE * member`` on the split of ``seed`` (``split_seed``),
    evaluated offline only."""
    from ompn_ros.cli.segment import write_node_config
    from ompn_ros.model.checkpoint import CheckpointError, load_checkpoint
    from ompn_ros.train.trainer import train, train_val_episodes

    run_dir = work / "runs" / f"{setting.name}{tag}_seed{seed}{f'_m{member}' if member else ''}"
    if member:
        overrides = {**(overrides or {}), "_train.split_seed": seed}
    model_cfg, train_cfg = build_configs(domain, base, setting, seed + MEMBER_SEED_STRIDE * member,
                                         iterations, run_dir, overrides)
    best_dir = run_dir / "best"
    info: dict[str, float] = {}
    if skip_trained and _trained_to_the_end(run_dir, model_cfg, train_cfg):
        print(f"   {run_dir.name}: trained to iteration {train_cfg.iterations} already, evaluating it")
        reuse = True
        info = {"train_seconds": float("nan"), "frames_per_second": float("nan")}
    if reuse:
        try:
            policy, extra = load_checkpoint(best_dir)
        except (CheckpointError, OSError) as exc:
            raise ReproduceError(
                f"cannot reuse a trained run: no usable checkpoint for {run_dir.name}: {exc}"
            ) from exc
        train_cfg = _stored_train_config(extra, train_cfg)
        info["best_iteration"] = float(extra.get("iteration", float("nan")))
    else:
        result = train(train_pool, model_cfg, train_cfg)
        policy = load_checkpoint(best_dir)[0] if best_dir.is_dir() else result.policy
        info = {"train_seconds": result.train_seconds, "best_iteration": result.best_iteration,
                "frames_per_second": result.frames / max(result.train_seconds, 1e-9)}
    _, val, n_val = train_val_episodes(train_pool, train_cfg)
    # without a validation split the trainer validates on training episodes: never tune on those
    run = evaluate_policy(domain, policy, test, val if n_val else (), online=not member)
    run["val"] = val if n_val else []
    run["row"].update(info)
    run["checkpoint"] = best_dir
    if run["tuning"] is not None:
        tuning = run["tuning"]
        write_node_config(run_dir / f"ompn_node_{domain}.yaml", domain, tuning["config"],
                          tuning["measured_on_val"],
                          f"the {tuning['n_val']} validation episodes of this run, checkpoint {best_dir}")
    return run


MEMBER_SEED_STRIDE = 1000
"""Ensemble member ``j`` of seed ``s`` trains with seed ``s + MEMBER_SEED_STRIDE * j`` (member 0 is
the seed's own run)."""


# TrainConfig fields that change how a run is executed, not what it learns
_RUNTIME_FIELDS = ("out_dir", "resume", "tensorboard", "threads", "progress", "eval_batch_size")


def _trained_to_the_end(run_dir: Path, model_cfg: Any, train_cfg: Any) -> bool:
    """True when ``run_dir`` holds a ``best/`` checkpoint and a ``last/`` one at ``train.iterations``
    that was trained with the requested model and training configuration (runtime fields aside).
    A finished run with another configuration is reported and trained again."""
    last = run_dir / "last"
    if not (run_dir / "best").is_dir() or not (last / "meta.json").is_file():
        return False
    try:
        extra = json.loads((last / "meta.json").read_text()).get("extra", {})
        stored_model = json.loads((last / "config.json").read_text())
        stored_train = _stored_train_config(extra, None)
    except (OSError, ValueError):
        return False
    if int(extra.get("iteration", -1)) != train_cfg.iterations:
        return False
    requested_train = train_cfg.to_dict()
    differ = sorted(k for k, v in model_cfg.to_dict().items() if stored_model.get(k) != v)
    if stored_train is not None:
        differ += sorted(f"train.{k}" for k, v in stored_train.to_dict().items()
                         if k not in _RUNTIME_FIELDS and requested_train.get(k) != v)
    if differ:
        print(f"   {run_dir.name}: finished with another configuration ({', '.join(differ)}), training again")
        return False
    return True


def _stored_train_config(extra: dict[str, Any], fallback: Any) -> Any:
    """The TrainConfig a checkpoint was trained with (its metadata), else ``fallback``."""
    from ompn_ros.train.trainer import TrainConfig

    stored = extra.get("train_config")
    return TrainConfig.from_dict(stored) if isinstance(stored, dict) else fallback


CONSTRAINED_KEYS = ("align", "f1_tol1", "f1_tol0")
"""Metrics of the constrained Top-K reported beside the paper's detector (``constrained_<key>``)."""
DEFAULT_MIN_LENGTH = 2
"""min_length of the constrained Top-K when a run has no validation episodes to tune it on."""


def parse_members(spec: str, names: Sequence[str]) -> dict[str, int]:
    """``--members``: ``'M'`` for every setting of the run, or ``'setting=M,...'`` (others get 1)."""
    text = spec.strip()
    if "=" not in text:
        try:
            count = int(text)
        except ValueError:
            raise ReproduceError(f"--members must be an integer M or SETTING=M pairs, got {spec!r}") from None
        per = {name: count for name in names}
    else:
        per = {name: 1 for name in names}
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, _, value = part.partition("=")
            if name not in per:
                raise ReproduceError(f"--members names {name!r}, which is not among the settings of this "
                                     f"run {list(names)}")
            try:
                per[name] = int(value)
            except ValueError:
                raise ReproduceError(f"--members {part!r}: the member count must be an integer") from None
    bad = {k: v for k, v in per.items() if v < 1}
    if bad:
        raise ReproduceError(f"--members must be >= 1 (1 = single models), got {bad}")
    return per


def tuned_min_length(val_p_hats: Sequence[np.ndarray], val: Sequence[Episode]) -> int:
    """The constrained Top-K's ``min_length`` chosen on validation episodes (never the test ones)."""
    from ompn_ros.train.evaluation import tune_min_length

    return tune_min_length(val_p_hats, val)[0] if val else DEFAULT_MIN_LENGTH


def evaluate_policy(
    domain: str, policy: Any, test: list[Episode], val: Sequence[Episode] = (), online: bool = True
) -> dict[str, Any]:
    """Offline (Top-K for Craft, automatic threshold for Dial; and the constrained Top-K with its
    ``min_length`` tuned on ``val``) and, with ``online``, online metrics on ``test``."""
    from ompn_ros.train.evaluation import teacher_forced_p_hat

    val_p_hats = teacher_forced_p_hat(policy, list(val))[0] if val else []
    min_length = tuned_min_length(val_p_hats, val)
    offline = offline_metrics(policy, test, min_length)
    row: dict[str, Any] = {"align_acc": offline["align"]}
    primary = "topk_" if domain == "craft" else "auto_"
    row.update({k: offline[primary + k] for k in METRIC_KEYS})
    row.update({f"constrained_{k}": offline[f"topkc_{k}"] for k in CONSTRAINED_KEYS})
    row["constrained_min_length"] = float(min_length)
    replays: list[Any] = []
    tuning = None
    if online:
        online_row, replays, tuning = online_metrics(policy, test, domain, val)
        row.update(online_row)
    return {"row": row, "p_hat": offline["p_hat"], "val_p_hat": val_p_hats, "replays": replays,
            "policy": policy, "tuning": tuning}


def aggregate(rows: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for key in rows[0]:
        values = np.asarray([r[key] for r in rows], dtype=np.float64)
        finite = values[np.isfinite(values)]
        mean = float(finite.mean()) if finite.size else float("nan")
        std = float(finite.std()) if finite.size else float("nan")
        out[key] = {"mean": mean, "std": std, "n": len(rows)}
    return out


# --- extras --------------------------------------------------------------------------------------


def k_sweep(p_hats: Sequence[np.ndarray], test: Sequence[Episode], ks: Sequence[int] = (2, 3, 4, 5, 6)):
    """Top-K precision/recall/F1 at tol 1 for fixed K (paper appendix K sweep)."""
    from ompn_ros.detect.offline import top_k_boundaries
    from ompn_ros.metrics import mean_f1

    table = {}
    for k in ks:
        preds = [top_k_boundaries(p, k) for p in p_hats]
        res = mean_f1(preds, [ep.boundaries for ep in test], 1)
        table[f"K={k}"] = {"f1_tol1": res.f1, "precision_tol1": res.precision, "recall_tol1": res.recall}
    return table


def threshold_sweep(p_hats: Sequence[np.ndarray], test: Sequence[Episode],
                    thresholds: Sequence[float] = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7)):
    """Alignment accuracy per fixed threshold and the automatic one (paper appendix, Dial)."""
    from ompn_ros.detect.offline import auto_threshold_boundaries, threshold_boundaries
    from ompn_ros.metrics import alignment_accuracy

    labels = [np.asarray(ep.subtask) for ep in test]
    table = {}
    for thr in thresholds:
        preds = [threshold_boundaries(p, thr, len(ep.boundaries)) for p, ep in zip(p_hats, test)]
        table[f"{thr:.1f}"] = {"align": alignment_accuracy(preds, labels, variant="authors")}
    preds = [auto_threshold_boundaries(p, len(ep.boundaries))[0] for p, ep in zip(p_hats, test)]
    table["auto"] = {"align": alignment_accuracy(preds, labels, variant="authors")}
    return table


def average_p_hats(p_hats_per_model: Sequence[Sequence[np.ndarray]]) -> list[np.ndarray]:
    """Episode by episode, the mean ``p_hat`` of several checkpoints (an ensemble's expansion
    distribution)."""
    if len(p_hats_per_model) < 2:
        raise ReproduceError("an ensemble needs the checkpoints of at least 2 models")
    return [np.mean(np.stack(per_episode), axis=0) for per_episode in zip(*p_hats_per_model, strict=True)]


def ensemble_scores(domain: str, p_hats_per_model: Sequence[Sequence[np.ndarray]],
                    test: Sequence[Episode], min_length: int = DEFAULT_MIN_LENGTH) -> dict[str, float]:
    """The domain's offline detector (Top-K for Craft, automatic threshold for Dial) and the
    constrained Top-K (``min_length``) on the test ``p_hat`` averaged over several checkpoints."""
    from ompn_ros.train.evaluation import decomposition_metrics

    mean = average_p_hats(p_hats_per_model)
    scores = decomposition_metrics(mean, test, primary="topk" if domain == "craft" else "auto",
                                   min_length=min_length)
    out = {"align_acc": scores["align"], "f1_tol1": scores["f1_tol1"], "f1_tol0": scores["f1_tol0"]}
    out.update({f"constrained_{k}": scores[f"topkc_{k}"] for k in CONSTRAINED_KEYS})
    return out


def member_ensemble_row(domain: str, member_runs: Sequence[dict[str, Any]], test: Sequence[Episode],
                        ensemble_dir: Path) -> dict[str, float]:
    """One seed's ensemble, written as an ensemble checkpoint (``ensemble_dir/ensemble.json``, what
    ``ompn_node`` loads) and scored on ``test``: offline, the members' test ``p_hat`` averaged with
    the constrained Top-K's ``min_length`` tuned on their shared validation split; online, the
    ensemble stepper replayed as live with the causal detector tuned on that split (written to
    ``ensemble_dir/ompn_node_<domain>.yaml``)."""
    from ompn_ros.cli.segment import write_node_config
    from ompn_ros.model.ensemble import write_ensemble
    from ompn_ros.model.factory import stepper_from_checkpoint

    val = member_runs[0]["val"]
    min_length = tuned_min_length(average_p_hats([r["val_p_hat"] for r in member_runs]) if val else [], val)
    row = ensemble_scores(domain, [r["p_hat"] for r in member_runs], test, min_length)
    row["constrained_min_length"] = float(min_length)
    write_ensemble(ensemble_dir, [r["checkpoint"] for r in member_runs],
                   {"constrained_min_length": min_length, "offline_metrics": dict(row)})
    online, _, tuning = online_metrics(None, test, domain, val, stepper=stepper_from_checkpoint(ensemble_dir))
    row.update({k: v for k, v in online.items() if k in ENSEMBLE_ONLINE_KEYS})
    if tuning is not None:
        write_node_config(ensemble_dir / f"ompn_node_{domain}.yaml", domain, tuning["config"],
                          tuning["measured_on_val"],
                          f"the {tuning['n_val']} validation episodes shared by the ensemble {ensemble_dir}")
    return row


ENSEMBLE_ONLINE_KEYS = ("online_f1_tol1", "online_align_strict", "online_delay_mean")
"""Online cells reported for an ensemble (with the detector tuned on its validation split)."""


def sweeps(domain: str, setting: str, wanted: set[str], p_hats: Sequence[np.ndarray],
           test: Sequence[Episode]) -> dict[str, Any]:
    """The appendix sweeps that apply to ``domain``: K for Craft, the threshold for Dial."""
    extras: dict[str, Any] = {}
    if "ksweep" in wanted and domain == "craft":
        extras[f"K sweep ({setting}, seed 0, tol=1)"] = k_sweep(p_hats, test)
    if "thresholds" in wanted and domain == "dial":
        extras[f"Threshold sweep ({setting}, seed 0, alignment)"] = threshold_sweep(p_hats, test)
    return extras


# --- reporting -----------------------------------------------------------------------------------

PAPER: dict[str, dict[str, tuple[int | None, int | None]]] = {
    "craft": {"full_nosketch": (93, 95), "partial_nosketch": (84, 89), "full_sketch": (97, 98),
              "partial_sketch": (72, 83)},
    "dial": {"nosketch": (87, None), "sketch": (82, None)},
}


def _fmt(cell: dict[str, float] | None, scale: float = 100.0, digits: int = 1) -> str:
    if cell is None or not np.isfinite(cell["mean"]):
        return "–"
    return f"{cell['mean'] * scale:.{digits}f} ({cell['std'] * scale:.{digits}f})"


UNSCALED_COLUMNS = {"members": 0, "min_length": 1, "delay_mean": 2}
"""Extras columns that are counts or steps, not fractions (suffix -> decimals shown)."""


def _cell(column: str, value: Any) -> str:
    """An extras-table cell: fractions in %, counts and step delays (``UNSCALED_COLUMNS``) as they are."""
    suffix = next((k for k in UNSCALED_COLUMNS if column.endswith(k)), None)
    scale, digits = (1.0, UNSCALED_COLUMNS[suffix]) if suffix else (100.0, 1)
    if isinstance(value, dict):
        return _fmt(value, scale, digits)
    return f"{scale * value:.{digits}f}"


def markdown(domain: str, results: dict[str, Any], extras: dict[str, Any], meta: dict[str, Any]) -> str:
    seeds = {name: int(row["align_acc"]["n"]) for name, row in results.items()}
    lines = [f"# OMPN reproduction: {domain}", "",
             f"Held-out test episodes: {meta['n_test']} (never trained on); seeds per setting: "
             f"{seeds}; mean (std) over seeds, in %. Paper numbers in brackets.", "",
             "Online = the causal detector of `ompn_node`, tuned for each checkpoint on that run's "
             "validation episodes; 'shipped det.' = the package's default detector settings instead.", "",
             "'Constrained' = Top-K restricted to subtasks of at least min_length steps that end at the "
             "episode's last step (our detector, min_length tuned on each run's validation episodes); the "
             "other offline columns use the paper's detector.", "",
             "| setting | align acc | F1 tol=1 | F1 tol=0 | constrained align | constrained F1 tol=1 | "
             "online F1 tol=1 | online align | "
             "online delay (steps) | false alarms / ep | online F1, shipped det. | paper align / F1 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, row in results.items():
        paper = PAPER[domain].get(name, (None, None))
        paper_txt = " / ".join("–" if v is None else str(v) for v in paper)
        lines.append(
            f"| {name} | {_fmt(row['align_acc'])} | {_fmt(row['f1_tol1'])} | {_fmt(row['f1_tol0'])} | "
            f"{_fmt(row.get('constrained_align'))} | {_fmt(row.get('constrained_f1_tol1'))} | "
            f"{_fmt(row['online_f1_tol1'])} | {_fmt(row['online_align_strict'])} | "
            f"{_fmt(row['online_delay_mean'], 1, 2)} | "
            f"{_fmt(row['online_false_alarms_per_episode'], 1, 2)} | "
            f"{_fmt(row.get('online_shipped_f1_tol1'))} | [{paper_txt}] |")
    for title, table in extras.items():
        lines += ["", f"## {title}", ""]
        first = next(iter(table.values()))
        cols = list(first)
        lines.append("| | " + " | ".join(cols) + " |")
        lines.append("|---|" + "---|" * len(cols))
        for key, cells in table.items():
            shown = [_cell(col, c) for col, c in cells.items()]
            lines.append(f"| {key} | " + " | ".join(shown) + " |")
    lines += ["", "## Wall time per stage (s)", ""]
    trained = meta.get("trained")
    if trained:
        lines += [f"- {k}: {v:.1f}" for k, v in trained.get("stages", {}).items()]
        lines.append(f"- total: {trained.get('total_seconds', float('nan')):.1f}")
        trained_by = [trained.get("command", []), *trained.get("parallel_commands", [])]
        lines += ["", "Trained by: " + "; ".join(f"`{' '.join(c)}`" for c in trained_by if c)]
        later = trained.get("later_commands", [])
        if later:
            lines += ["", "Runs added later in the same work directory by: "
                      + "; ".join(f"`{' '.join(c)}`" for c in later)]
        lines += ["", f"Re-evaluated without training (`{' '.join(meta['command'])}`):", ""]
    lines += [f"- {k}: {v:.1f}" for k, v in meta["stages"].items()]
    lines.append(f"- total: {meta['total_seconds']:.1f}")
    return "\n".join(lines) + "\n"


def save_figures(domain: str, setting: str, test: Sequence[Episode], run: dict[str, Any], out: Path,
                 count: int = 3) -> list[str]:
    from ompn_ros.detect.offline import auto_threshold_boundaries, top_k_boundaries
    from ompn_ros.plotting import plot_episode

    paths = []
    for i, (ep, p_hat, replay) in enumerate(zip(test, run["p_hat"], run["replays"])):
        if i >= count:
            break
        k = len(ep.boundaries)
        offline = top_k_boundaries(p_hat, k) if domain == "craft" else auto_threshold_boundaries(p_hat, k)[0]
        path = out / f"{domain}_{setting}_episode{i}.png"
        plot_episode(path, replay.pi, replay.pi_end, replay.scores, true_boundaries=ep.boundaries.tolist(),
                     detected_boundaries=replay.boundary_steps.tolist(), offline_boundaries=list(offline),
                     title=f"{domain} {setting}, held-out episode {i} ({ep.task}, {ep.length} steps)")
        paths.append(str(path))
    return paths


def ship(domain: str, checkpoint: Path, provenance: dict[str, Any]) -> Path:
    """Copy ``checkpoint`` into the package as the shipped one, weights stored in float16 (half the size)."""
    from ompn_ros.checkpoints import HERE, SHIPPED
    from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint

    target = HERE / SHIPPED[domain]
    policy, _ = load_checkpoint(checkpoint)
    save_checkpoint(target, policy, extra={"provenance": provenance}, weights_dtype="float16")
    (target / "provenance.json").write_text(json.dumps(provenance, indent=1, sort_keys=True) + "\n")
    return target


# --- main ----------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ompn_reproduce", description=__doc__.splitlines()[0])
    p.add_argument("domain", choices=sorted(SETTINGS))
    p.add_argument("--settings", default="", help="comma-separated subset (default: all of the domain)")
    p.add_argument("--seeds", type=int, default=5,
                   help="training seeds per setting (default 5, as the paper)")
    p.add_argument("--episodes", type=int, default=None,
                   help="demonstrations (Craft: per task, default 500; Dial: total, default 1400)")
    p.add_argument("--data-seed", type=int, default=0, help="seed of the demonstration collection")
    p.add_argument("--iterations", type=int, default=None, help="override train.iterations")
    p.add_argument("--test-ratio", type=float, default=DEFAULT_TEST_RATIO)
    p.add_argument("--config", type=Path, default=None,
                   help="train YAML (default config/train_<domain>.yaml)")
    p.add_argument("--members", default="1", metavar="M | SETTING=M,...",
                   help="ensemble members per seed: M for every setting, or per setting (e.g. "
                        "full_nosketch=3,partial_nosketch=5; settings not named get none). Default 1 = "
                        "single models only; with M > 1 every seed also trains M-1 members on its split "
                        "and their ensemble is reported in its own table")
    p.add_argument("--extras", default="all", help="all | none | comma list of "
                   "ksweep,thresholds,ablations,ensemble (ensemble: the seeds' p_hat averaged, offline)")
    p.add_argument("--work", type=Path, default=None, help="work directory (default runs/reproduce_<domain>)")
    p.add_argument("--results", type=Path, default=Path("results"))
    p.add_argument("--threads", type=int, default=None, help="override train.threads (torch threads)")
    p.add_argument("--evaluate", type=Path, default=None, metavar="CHECKPOINT",
                   help="skip training: evaluate this checkpoint on the held-out split of the first setting")
    p.add_argument("--reevaluate", action="store_true",
                   help="skip training: re-evaluate the existing best/ checkpoints of every setting, "
                        "seed and ablation in --work (e.g. after a change to the evaluation); "
                        "training figures are kept from the previous results")
    p.add_argument("--skip-trained", action="store_true",
                   help="do not retrain a run whose last/ checkpoint reached train.iterations with the same "
                        "model and training config (continue an interrupted reproduction, add seeds or "
                        "extras to a finished one); it is evaluated as is")
    p.add_argument("--merge", action="store_true",
                   help="keep the other settings already in results/<domain>.json (runs split over calls)")
    p.add_argument("--ablations", default=",".join(ABLATIONS),
                   help=f"comma list for the ablation table (default all: {','.join(ABLATIONS)})")
    p.add_argument("--ship", action="store_true", help="copy the primary seed-0 checkpoint into the package")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s: %(message)s")
    try:
        return _run(args, argv if argv is not None else sys.argv[1:])
    except ReproduceError as exc:
        print(f"ompn_reproduce: error: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace, argv: Sequence[str]) -> int:
    import torch

    domain = args.domain
    args.argv = list(argv)
    start = time.perf_counter()
    timer = Timer()
    work = args.work or Path("runs") / f"reproduce_{domain}"
    names = [s for s in args.settings.split(",") if s] or list(SETTINGS[domain])
    unknown = [s for s in names if s not in SETTINGS[domain]]
    if unknown:
        raise ReproduceError(f"unknown settings {unknown} for {domain}; known: {sorted(SETTINGS[domain])}")
    extras_wanted = set(EXTRAS) if args.extras == "all" else (
        set() if args.extras == "none" else set(args.extras.split(",")))
    if extras_wanted - set(EXTRAS):
        raise ReproduceError(f"unknown extras {sorted(extras_wanted - set(EXTRAS))}; known: {list(EXTRAS)}")
    members_of = parse_members(args.members, names)
    episodes_n = args.episodes or DEFAULT_EPISODES[domain]
    base = load_train_config(domain, args.config)
    if args.threads is not None:
        base["train"]["threads"] = args.threads
    torch.set_num_threads(int(base["train"].get("threads", 2)) or 2)

    data: dict[bool, tuple[list[Episode], list[Episode]]] = {}
    for partial in sorted({SETTINGS[domain][n].partial for n in names}):
        obs = "partial" if partial else "full"
        bags = timer.run(f"collect {domain} {obs}", collect_bags,
                         domain, partial, episodes_n, args.data_seed, work)
        episodes = timer.run(f"read bags {obs}", read_bags, domain, bags)
        data[partial] = held_out_split(episodes, args.test_ratio, args.data_seed)
        n_pool, n_test = len(data[partial][0]), len(data[partial][1])
        print(f"   {n_pool} train+val episodes, {n_test} held-out test episodes")

    results: dict[str, Any] = {}
    previous = args.results / f"{domain}.json"
    old_results = json.loads(previous.read_text()) if previous.is_file() else {}
    stage = "re-evaluate" if args.reevaluate else "train+eval"
    if args.merge:
        results.update({k: v for k, v in old_results.items() if k not in names})
    runs: dict[str, dict[str, Any]] = {}
    figures: list[str] = []
    args.results.mkdir(parents=True, exist_ok=True)
    if args.evaluate is not None:
        from ompn_ros.model.checkpoint import CheckpointError, load_checkpoint

        setting = SETTINGS[domain][names[0]]
        test = data[setting.partial][1]
        try:
            policy = load_checkpoint(args.evaluate)[0]
        except CheckpointError as exc:
            raise ReproduceError(f"--evaluate takes one checkpoint directory (ensembles are scored with "
                                 f"--members): {exc}") from exc
        run = timer.run(f"evaluate {args.evaluate}", evaluate_policy, domain, policy, test)
        print("   " + ", ".join(f"{k} {v:.3f}" for k, v in run["row"].items() if isinstance(v, float)))
        # Re-evaluation refreshes the metric cells and keeps the training figures of an earlier run.
        if previous.is_file():
            results.setdefault(setting.name, json.loads(previous.read_text()).get(setting.name, {}))
        results.setdefault(setting.name, {}).update(aggregate([run["row"]]))
        figures += save_figures(domain, setting.name, test, run, args.results / "figures")
        _write(args, domain, results, sweeps(domain, setting.name, extras_wanted, run["p_hat"], test),
               timer, start, figures, data)
        return 0
    ensembles: dict[str, dict[str, float]] = {}
    member_ensembles: dict[str, dict[str, dict[str, float]]] = {}
    want_ensemble = "ensemble" in extras_wanted and args.seeds >= 2
    if "ensemble" in extras_wanted and not want_ensemble:
        print("   ensemble extra skipped: it averages several seeds and needs --seeds 2 or more")
    for name in names:
        setting = SETTINGS[domain][name]
        pool, test = data[setting.partial]
        rows, member_rows = [], []
        seed_p_hats = []
        for seed in range(args.seeds):
            run = timer.run(f"{stage} {name} seed {seed}", run_setting, domain, setting, seed, pool, test,
                            base, args.iterations, work, reuse=args.reevaluate,
                            skip_trained=args.skip_trained)
            print("   " + ", ".join(f"{k} {v:.3f}" for k, v in run["row"].items() if isinstance(v, float)))
            rows.append(run["row"])
            if want_ensemble:
                seed_p_hats.append(run["p_hat"])
            if seed == 0:
                runs[name] = run
            if members_of[name] > 1:
                members = [run] + [
                    timer.run(f"{stage} {name} seed {seed} member {j}", run_setting, domain, setting, seed,
                              pool, test, base, args.iterations, work, reuse=args.reevaluate,
                              skip_trained=args.skip_trained, member=j)
                    for j in range(1, members_of[name])]
                ensemble_dir = work / "runs" / f"{name}_seed{seed}_ensemble{members_of[name]}"
                scores = timer.run(f"ensemble {name} seed {seed}", member_ensemble_row,
                                   domain, members, test, ensemble_dir)
                member_rows.append({"members": float(len(members)), **scores})
                print(f"   ensemble of {members_of[name]}: " + ", ".join(
                    f"{k} {v:.3f}" for k, v in member_rows[-1].items()))
        results[name] = aggregate(rows)
        if member_rows:
            member_ensembles[name] = aggregate(member_rows)
        if want_ensemble:
            lengths = [int(r["constrained_min_length"]) for r in rows]
            ensembles[name] = ensemble_scores(domain, seed_p_hats, test,
                                              min(set(lengths), key=lambda v: (-lengths.count(v), v)))
        if args.reevaluate:
            kept = old_results.get(name, {})
            results[name].update({k: kept[k] for k in TRAINING_CELLS if k in kept})
        figures += save_figures(domain, name, test, runs[name], args.results / "figures")
        _write(args, domain, results, {}, timer, start, figures, data)

    primary = PRIMARY[domain] if PRIMARY[domain] in runs else names[0]
    pool, test = data[SETTINGS[domain][primary].partial]
    extras = sweeps(domain, primary, extras_wanted, runs[primary]["p_hat"], test)
    if member_ensembles:
        title = ("Ensembles per seed (members share the seed's split and differ in initialisation; "
                 f"p_hat averaged; mean (std) over {args.seeds} seeds)")
        extras[title] = member_ensembles
    if ensembles:
        extras[f"Ensemble of the {args.seeds} seeds (p_hat averaged offline; constrained Top-K with the "
               "min_length most seeds chose)"] = ensembles
    if "ablations" in extras_wanted:
        table = {}
        chosen = [a for a in args.ablations.split(",") if a]
        unknown_ab = [a for a in chosen if a not in ABLATIONS]
        if unknown_ab:
            raise ReproduceError(f"unknown ablations {unknown_ab}; known: {sorted(ABLATIONS)}")
        for ab_name in chosen:
            overrides = ABLATIONS[ab_name]
            run = timer.run(f"{'re-evaluate ' if args.reevaluate else ''}ablation {ab_name}", run_setting,
                            domain, SETTINGS[domain][primary], 0, pool, test, base, args.iterations, work,
                            overrides, f"_{ab_name}", reuse=args.reevaluate,
                            skip_trained=args.skip_trained)
            table[ab_name] = {k: run["row"][k] for k in ("align_acc", "f1_tol1", "online_f1_tol1")}
        extras[f"Ablations ({primary}, seed 0)"] = table

    meta = _write(args, domain, results, extras, timer, start, figures, data)
    if args.ship:
        run = runs[primary]
        provenance = {"command": ["ompn_reproduce", *argv], "setting": primary, "seed": 0,
                      "data_seed": args.data_seed, "held_out_metrics": run["row"],
                      "results": str(args.results)}
        target = timer.run("ship checkpoint", ship, domain, run["checkpoint"], provenance)
        print(f"   shipped {target}")
    print(f"total wall time {time.perf_counter() - start:.1f} s; results in {args.results}/{domain}.md")
    print(json.dumps({k: {m: round(v["mean"], 4) for m, v in row.items() if m in ("align_acc", "f1_tol1")}
                      for k, row in results.items()}))
    return 0 if meta else 1


def _write(args, domain, results, extras, timer, start, figures, data) -> dict[str, Any]:
    meta = {"seeds": args.seeds, "stages": dict(timer.stages), "total_seconds": time.perf_counter() - start,
            "n_test": {("partial" if k else "full"): len(v[1]) for k, v in data.items()},
            "figures": figures, "command": ["ompn_reproduce", *args.argv]}
    extras_file = args.results / f"{domain}_extras.json"
    if args.reevaluate and extras_file.is_file():
        # the tables come from the trained run: keep its command and stage times beside the re-evaluation
        trained = json.loads(extras_file.read_text()).get("meta", {})
        if "trained" in trained:
            trained = trained["trained"]
        keep = ("command", "parallel_commands", "later_commands", "stages", "total_seconds")
        meta["trained"] = {k: trained[k] for k in keep if k in trained}
    (args.results / f"{domain}.json").write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    extras_doc = {"extras": extras, "meta": meta}
    extras_file.write_text(json.dumps(extras_doc, indent=1) + "\n")
    (args.results / f"{domain}.md").write_text(markdown(domain, results, extras, meta))
    return meta


if __name__ == "__main__":
    sys.exit(main())
