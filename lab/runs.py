"""Train one run of the reproduction (a setting, a seed, maybe an ablation or ensemble member), or
reload its finished checkpoint, and score it on the held-out test episodes.

Run directories: ``<work>/runs/<RunSpec.name>/`` with the trainer's ``best/`` and ``last/``
checkpoints and, when the detector was tuned, ``ompn_node_<domain>.yaml``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lab.scoring import Evaluation, evaluate_policy
from lab.spec import REPRODUCTION_ITERATIONS, ReproduceError, RunSpec
from ompn_ros import layout
from ompn_ros.app.training import load_config
from ompn_ros.data.episode import Episode
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import CheckpointError
from ompn_ros.paths import config_file
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.restart import attempt_config, read_kept
from ompn_ros.train.trainer import train, train_val_episodes

BaseConfig = dict[str, dict[str, Any]]
RUNTIME_FIELDS = ("out_dir", "resume", "tensorboard", "threads", "progress", "eval_batch_size")
"""TrainConfig fields that change how a run is executed, not what it learns."""


def load_train_config(domain: str, path: Path | None) -> BaseConfig:
    """The train YAML of the reproduction (default: the shipped ``config/train_<domain>.yaml``)."""
    return load_config(str(path or config_file(f"train_{domain}.yaml")))


def pin_fixed_length(base: BaseConfig, domain: str, shipped: bool) -> None:
    """The reproduction trains a fixed number of iterations, whatever ``ompn_train``'s default: early
    stopping off (``patience: 0``) and, with the shipped config, :data:`REPRODUCTION_ITERATIONS`
    instead of its early-stopping cap, so that the committed results stay reproducible."""
    base["train"]["patience"] = 0
    if shipped:
        base["train"]["iterations"] = REPRODUCTION_ITERATIONS[domain]


def build_configs(spec: RunSpec, base: BaseConfig, out_dir: Path) -> tuple[OMPNConfig, TrainConfig]:
    """Model and training configs of ``spec``: the base YAML, the domain's sizes, the setting's
    sketch, the seed, and the ablation's overrides (``_train.`` prefixed keys go to training)."""
    dom = layout.DOMAINS[spec.domain]
    model = {
        **base["model"],
        "obs_dim": dom.obs_dim,
        "action_type": dom.action_type,
        "action_dim": dom.action_dim,
    }
    train_fields = {**base["train"], "seed": spec.train_seed, "out_dir": str(out_dir), "progress": False}
    if spec.setting.sketch:
        model["sketch_mode"], model["sketch_vocab"] = "sum", dom.sketch_vocab
    else:
        model["sketch_mode"], model["sketch_vocab"] = "none", 0
    if spec.iterations is not None:
        train_fields["iterations"] = spec.iterations
    overrides = dict(spec.overrides)
    if spec.member:
        overrides["_train.split_seed"] = spec.seed
    for key, value in overrides.items():
        if key.startswith("_train."):
            train_fields[key.removeprefix("_train.")] = value
        else:
            model[key] = value
    return OMPNConfig.from_dict(model), TrainConfig.from_dict(train_fields)


def stored_train_config(extra: dict[str, Any], fallback: TrainConfig | None) -> TrainConfig | None:
    """The TrainConfig a checkpoint was trained with (its metadata), else ``fallback``."""
    stored = extra.get("train_config")
    return TrainConfig.from_dict(stored) if isinstance(stored, dict) else fallback


def trained_to_the_end(run_dir: Path, model_cfg: OMPNConfig, train_cfg: TrainConfig) -> bool:
    """True when ``run_dir`` holds a ``best/`` checkpoint and a ``last/`` one at ``train.iterations``
    that was trained with the requested model and training configuration (runtime fields aside; a run
    the restart rule trained again holds its kept attempt, :mod:`ompn_ros.train.restart`, with that
    attempt's seed).
    A finished run with another configuration is reported and trained again."""
    last = run_dir / "last"
    if not (run_dir / "best").is_dir() or not (last / "meta.json").is_file():
        return False
    try:
        extra = json.loads((last / "meta.json").read_text()).get("extra", {})
        stored_model = json.loads((last / "config.json").read_text())
        stored_train = stored_train_config(extra, None)
    except (OSError, ValueError):
        return False
    if int(extra.get("iteration", -1)) != train_cfg.iterations:
        return False
    requested_train = attempt_config(train_cfg, read_kept(run_dir)).to_dict()  # the kept attempt's seed
    differ = sorted(k for k, v in model_cfg.to_dict().items() if stored_model.get(k) != v)
    if stored_train is not None:
        differ += sorted(
            f"train.{k}"
            for k, v in stored_train.to_dict().items()
            if k not in RUNTIME_FIELDS and requested_train.get(k) != v
        )
    if differ:
        print(f"   {run_dir.name}: finished with another configuration ({', '.join(differ)}), training again")
        return False
    return True


def _reload(run_dir: Path, train_cfg: TrainConfig) -> tuple[Any, TrainConfig, dict[str, float]]:
    try:
        policy, extra = load_checkpoint(run_dir / "best")
    except (CheckpointError, OSError) as exc:
        raise ReproduceError(
            f"cannot reuse a trained run: no usable checkpoint for {run_dir.name}: {exc}"
        ) from exc
    stored = stored_train_config(extra, train_cfg)
    assert stored is not None
    return policy, stored, {"best_iteration": float(extra.get("iteration", float("nan")))}


def run_setting(
    spec: RunSpec, train_pool: list[Episode], test: list[Episode], base: BaseConfig, work: Path
) -> Evaluation:
    """Train ``spec``, or with ``spec.reuse`` reload its existing ``best/`` checkpoint, and score it on
    the held-out ``test`` episodes (the detectors tuned on the run's validation split).

    An ensemble member (``spec.member`` > 0) trains with seed ``seed + MEMBER_SEED_STRIDE * member`` on
    the split of ``seed`` and is scored offline only."""
    run_dir = work / "runs" / spec.name
    model_cfg, train_cfg = build_configs(spec, base, run_dir)
    best_dir = run_dir / "best"
    reuse, info = spec.reuse, {}
    if spec.skip_trained and trained_to_the_end(run_dir, model_cfg, train_cfg):
        print(f"   {run_dir.name}: trained to iteration {train_cfg.iterations} already, evaluating it")
        reuse, info = True, {"train_seconds": float("nan"), "frames_per_second": float("nan")}
    if reuse:
        policy, train_cfg, loaded = _reload(run_dir, train_cfg)
        info.update(loaded)
    else:
        result = train(train_pool, model_cfg, train_cfg)
        policy = load_checkpoint(best_dir)[0] if best_dir.is_dir() else result.policy
        info = {
            "train_seconds": result.train_seconds,
            "best_iteration": result.best_iteration,
            "frames_per_second": result.frames / max(result.train_seconds, 1e-9),
        }
    _, val, n_val = train_val_episodes(train_pool, train_cfg)
    # without a validation split the trainer validates on training episodes: never tune on those
    run = evaluate_policy(spec.domain, policy, test, val if n_val else (), online=not spec.member)
    run.row.update(info)
    run.checkpoint = best_dir
    if run.tuning is not None:
        run.tuning.write(
            run_dir / f"ompn_node_{spec.domain}.yaml", spec.domain, f"of this run, checkpoint {best_dir}"
        )
    return run
