"""Behaviour cloning from a YAML config and bags (or synthetic data): the library of ``ompn_train``.

The config has three sections (``model``: :class:`~ompn_ros.model.config.OMPNConfig`, ``train``:
:class:`~ompn_ros.train.config.TrainConfig`, ``data``: ``domain``, ``reader_spec``, ``on_error``,
``cache``, ``cache_workers``: per-bag cache entries built in parallel, ``action_dim``);
``section.key=value`` overrides are parsed as YAML.  What the bag reader used and dropped is printed
and stored with the run (``read_report.json`` / ``.txt``), with the tolerance ``model.still_tolerance:
auto`` (the default) chose from the episodes (:func:`resolve_still`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ompn_ros.app.errors import TrainSetupError
from ompn_ros.app.idle_record import read_idle_speed, record_idle_speed
from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.cache import EpisodeArrays, load_arrays, load_dataset_arrays
from ompn_ros.data.cuts import AUTO, check_setting, choose_tolerance
from ompn_ros.data.lerobot import DatasetSpec
from ompn_ros.data.reader import BagFacts, ReaderSpec, final_row_guessed
from ompn_ros.layout import DOMAINS
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train.candidates import resolve_candidates
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.device import resolve_device
from ompn_ros.train.distributed import DistContext, broadcast_text, init_distributed, shutdown
from ompn_ros.train.synthetic import SyntheticKind, make_dataset, synthetic_spec
from ompn_ros.train.trainer import train

LOG = logging.getLogger("ompn_ros.train")
SECTIONS = ("model", "train", "data")
RUN_OUTPUTS = (
    "best",
    "last",
    "train_state",
    "tb",
    "log.jsonl",
    "summary.json",
    "read_report.json",
    "read_report.txt",
    "candidates",
    "candidates.json",
    "final_observation",
    "final_observation.json",
)
"""What ``ompn_train`` writes into its output directory (``--overwrite`` removes exactly these)."""


def _number_or_text(value: Any) -> Any:
    """YAML 1.1 reads ``5e-4`` (no dot) as a string; turn such numeric strings into floats."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def load_config(path: str | None) -> dict[str, dict[str, Any]]:
    """Read the YAML config (or an empty one) and check its sections."""
    config: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    if path is None:
        return config
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError) as exc:
        raise TrainSetupError(f"cannot read config file {path}: {exc}") from exc
    except yaml.YAMLError as exc:
        raise TrainSetupError(f"config file {path} is not valid YAML: {exc}") from exc
    if not isinstance(raw, dict):
        raise TrainSetupError(f"config file {path} must hold a mapping with sections {SECTIONS}")
    for key, value in raw.items():
        if key not in SECTIONS:
            raise TrainSetupError(f"config file {path}: unknown section '{key}' (expected {SECTIONS})")
        if not isinstance(value, dict):
            raise TrainSetupError(f"config file {path}: section '{key}' must be a mapping")
        config[key].update({k: _number_or_text(v) for k, v in value.items()})
    return config


def apply_overrides(config: dict[str, dict[str, Any]], overrides: list[str]) -> None:
    """Apply ``section.key=value`` overrides (value parsed as YAML) in place."""
    for item in overrides:
        if "=" not in item:
            raise TrainSetupError(f"--set {item!r}: expected section.key=value")
        dotted, text = item.split("=", 1)
        if "." not in dotted:
            raise TrainSetupError(f"--set {item!r}: key must be section.key with section in {SECTIONS}")
        section, key = dotted.split(".", 1)
        if section not in SECTIONS:
            raise TrainSetupError(f"--set {item!r}: unknown section '{section}' (expected {SECTIONS})")
        try:
            config[section][key] = _number_or_text(yaml.safe_load(text))
        except yaml.YAMLError as exc:
            raise TrainSetupError(f"--set {item!r}: value is not valid YAML: {exc}") from exc


def check_device(config: dict[str, dict[str, Any]]) -> None:
    """Refuse the configured ``train.device`` when this machine lacks it ('cuda' without a GPU): one line,
    before any bag is read."""
    resolve_device(str(config["train"].get("device", "auto")))


def prepare_out_dir(out: Path, resume: bool, overwrite: bool) -> None:
    """Refuse a non-empty ``out`` unless resuming, or clear ``ompn_train``'s outputs with ``overwrite``.

    Under ``torchrun`` only rank 0 checks (the other ranks start while rank 0 may be writing).
    """
    if resume and overwrite:
        raise TrainSetupError("--resume and --overwrite exclude each other")
    if int(os.environ.get("RANK", "0")) != 0 or resume or not out.is_dir() or not any(out.iterdir()):
        return
    if not overwrite:
        raise TrainSetupError(
            f"output directory {out} is not empty; pass --resume to continue its run "
            "or --overwrite to replace it"
        )
    for name in RUN_OUTPUTS:
        target = out / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()


def _data_int(data: dict[str, Any], key: str, default: int | None) -> int:
    """``data[key]`` (or ``default``) as an int; :class:`TrainSetupError` naming ``data.key`` otherwise."""
    value = data.get(key, default)
    try:
        return int(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise TrainSetupError(f"data.{key} must be an integer, got {value!r}") from exc


@dataclass
class TrainingData:
    """Episodes to train on, the model fields they fix, and the bag reader's report (bags only): the
    document written beside the run (``report``) and the read's facts as data (``facts``, what the
    training uses: :meth:`~ompn_ros.data.reader.ReadReport.facts`; none for synthetic data)."""

    episodes: list[Any]
    fields: dict[str, Any]
    vocab: int | None = None
    report: dict[str, Any] = field(default_factory=dict)
    facts: tuple[BagFacts, ...] = ()


def synthetic_data(task: SyntheticKind, episodes: int, data: dict[str, Any]) -> TrainingData:
    """A synthetic task (smoke runs): episodes and the task's sizes."""
    found = make_dataset(task, episodes, seed=_data_int(data, "synthetic_seed", 0))
    obs_dim, action_type, action_dim, vocab = synthetic_spec(task)
    return TrainingData(
        found, {"obs_dim": obs_dim, "action_type": action_type, "action_dim": action_dim}, vocab
    )


def shared_arrays(load: Callable[[], EpisodeArrays], ctx: DistContext | None = None,
                  share: Callable[[str, DistContext], str] = broadcast_text) -> EpisodeArrays:
    """``load()`` in one process.  Under ``torchrun`` rank 0 alone loads (reads the bags into the cache)
    and ``share``s the cache entry's path; the other ranks open it memory-mapped and so read only the
    episodes of their shards (without a cache, ``data.cache: false``, every rank reads the bags)."""
    ctx = ctx if ctx is not None else init_distributed()
    if not ctx.enabled:
        return load()
    arrays = load() if ctx.is_main else None
    path = share(str(arrays.cache_path or "") if arrays is not None else "", ctx)
    if arrays is not None:
        return arrays
    if not path:
        return load()
    try:
        return EpisodeArrays.load(Path(path))
    except OSError as exc:
        raise TrainSetupError(f"rank {ctx.rank} cannot open the cache entry {path} that rank 0 built "
                              f"({exc}): put OMPN_CACHE_DIR on a disk every machine sees") from exc


def reader_spec(data: dict[str, Any]) -> ReaderSpec:
    """The reader spec of the ``data`` section: ``data.reader_spec``'s file, or ``data.domain``'s preset."""
    domain_name = data.get("domain")
    if data.get("reader_spec"):
        return ReaderSpec.from_yaml(data["reader_spec"])
    if domain_name in DOMAINS:
        return ReaderSpec.for_domain(domain_name)
    raise TrainSetupError(
        f"data.domain must be one of {sorted(DOMAINS)}, or give data.reader_spec (a reader YAML such as "
        f"config/reader_jointstate_example.yaml) for your own bags; got domain {domain_name!r}"
    )


def bag_data(bags: list[str], data: dict[str, Any], spec: ReaderSpec | None = None) -> TrainingData:
    """Episodes from ``bags`` (cached reader; ``data.on_error`` raise | skip_tail) and the model sizes.
    ``spec``: the reader spec (default: :func:`reader_spec` of ``data``)."""
    domain_name = data.get("domain")
    spec = reader_spec(data) if spec is None else spec
    on_error = data.get("on_error", "raise")
    workers, cached = _data_int(data, "cache_workers", 0), bool(data.get("cache", True))
    if workers < 0:
        raise TrainSetupError(f"data.cache_workers must be >= 0 (0: one entry for all bags), got {workers}")
    arrays = shared_arrays(lambda: load_arrays(bags, spec=spec, on_error=on_error, use_cache=cached,
                                               workers=workers))  # workers: per-bag entries
    episodes = arrays.episodes()
    if not episodes:
        raise TrainSetupError(f"no episodes found in {bags}")
    report = {
        "bags": [str(b) for b in bags],
        "on_error": on_error,
        "episodes": len(episodes),
        "cache_hit": bool(arrays.cache_hit),
        "summary": arrays.report,
    }
    if domain_name not in DOMAINS:
        return TrainingData(episodes, fields_from_episodes(episodes, data), None, report, arrays.facts)
    dom = DOMAINS[domain_name]
    sizes = {"obs_dim": dom.obs_dim, "action_type": dom.action_type, "action_dim": dom.action_dim}
    return TrainingData(episodes, sizes, dom.sketch_vocab, report, arrays.facts)


def dataset_data(dataset: str, data: dict[str, Any], spec_file: str | None = None) -> TrainingData:
    """Episodes of the LeRobot dataset at ``dataset`` (cached, read one frame file at a time) under the
    dataset spec of ``spec_file`` (none: the default features) and the model sizes (``data.domain``'s, else
    the dataset's, with ``data.action_dim`` for discrete actions)."""
    spec = DatasetSpec.from_yaml(spec_file) if spec_file else DatasetSpec()
    arrays = shared_arrays(lambda: load_dataset_arrays(dataset, spec))
    episodes = arrays.episodes()
    report = {"dataset": str(dataset), "dataset_spec": spec.to_dict(),
              "episodes": len(episodes), "cache_hit": bool(arrays.cache_hit), "summary": arrays.report}
    domain_name = data.get("domain")
    if domain_name not in DOMAINS:
        return TrainingData(episodes, fields_from_episodes(episodes, data), None, report, arrays.facts)
    dom = DOMAINS[domain_name]
    sizes = {"obs_dim": dom.obs_dim, "action_type": dom.action_type, "action_dim": dom.action_dim}
    return TrainingData(episodes, sizes, dom.sketch_vocab, report, arrays.facts)


def fields_from_episodes(episodes: list[Any], data: dict[str, Any]) -> dict[str, Any]:
    """Model sizes for a user's own bags: from the data, with ``data.action_dim`` for discrete actions."""
    first = episodes[0]
    continuous = first.actions.ndim == 2
    if continuous:
        action_dim = int(first.actions.shape[1])
    elif "action_dim" in data:
        action_dim = _data_int(data, "action_dim", None)
    else:
        raise TrainSetupError(
            "discrete actions from your own bags need data.action_dim (the number of actions, without 'done')"
        )
    return {
        "obs_dim": int(first.observations.shape[1]),
        "action_type": "continuous" if continuous else "discrete",
        "action_dim": action_dim,
    }


def weights_hash(policy: Any) -> str:
    """SHA-256 over the policy's state dict (names, shapes and raw bytes), for cross-rank checks."""
    digest = hashlib.sha256()
    for name, tensor in sorted(policy.state_dict().items()):
        digest.update(name.encode())
        digest.update(str(tuple(tensor.shape)).encode())
        digest.update(tensor.detach().contiguous().cpu().numpy().tobytes())
    return digest.hexdigest()


def build_configs(
    config: dict[str, dict[str, Any]], data: TrainingData, out: Path, resume: bool, quiet: bool
) -> tuple[OMPNConfig, TrainConfig]:
    """The validated model and training configs: the file's sections, the data's sizes, the CLI's flags
    (``model.still_tolerance: auto`` resolved from the episodes, :func:`resolve_still`)."""
    model_fields = {**config["model"], **data.fields}
    model_fields["still_tolerance"] = resolve_still(model_fields.get("still_tolerance", AUTO), data)
    if model_fields.get("sketch_mode") == "sum" and not model_fields.get("sketch_vocab") and data.vocab:
        model_fields["sketch_vocab"] = data.vocab
    train_fields = {**config["train"], "out_dir": str(out), "resume": bool(resume)}
    if quiet:
        train_fields["progress"] = False
    train_config = TrainConfig.from_dict(train_fields)
    guessed = final_row_guessed(data.facts)
    return OMPNConfig.from_dict(model_fields), resolve_candidates(train_config, guessed,
                                                                  labelled(train_config, data))


def resolve_still(setting: Any, data: TrainingData) -> float:
    """``model.still_tolerance`` as a number: a given one as it is, ``auto`` (the default) chosen from
    ``data``'s episodes without labels (:func:`ompn_ros.data.cuts.choose_tolerance`); the choice joins the
    read report when the data has one (``still`` and a line of its ``summary``; synthetic data has none, so
    ``ompn_train --synthetic`` prints and writes no read summary), and the checkpoint stores the number."""
    try:
        value = check_setting(setting, "model.still_tolerance")
    except ValueError as exc:
        raise TrainSetupError(str(exc)) from None
    if value != AUTO:
        return float(value)
    choice = choose_tolerance(data.episodes)
    LOG.info("%s", choice.summary())
    if data.report and data.report.get("still") != choice.as_dict():
        data.report["still"] = choice.as_dict()
        if "summary" in data.report:
            data.report["summary"] = f"{data.report['summary']}\n{choice.summary()}"
    return choice.tolerance


def labelled(train_config: TrainConfig, data: TrainingData) -> bool:
    """Whether validation labels select the checkpoint: ``train.labels: auto`` and every episode labelled."""
    return train_config.labels == "auto" and all(ep.subtask is not None for ep in data.episodes)


def _record_idle(out: Path, facts: tuple[BagFacts, ...]) -> None:
    """The idle speed the read used (its ``facts``), beside ``best/`` and ``last/`` (for ``ompn_node``'s
    ``idle_speed: auto``, :mod:`ompn_ros.app.idle_record`)."""
    record = read_idle_speed(facts)
    for name in ("best", "last"):
        if record is not None and (out / name).is_dir():
            record_idle_speed(out / name, record)


def run_training(
    data: TrainingData, model_config: OMPNConfig, train_config: TrainConfig, out: Path
) -> dict[str, Any] | None:
    """Train (one process, or one rank under ``torchrun``); rank 0 writes and returns ``summary.json``."""
    ctx = init_distributed()
    try:
        result = train(data.episodes, model_config, train_config, dist_ctx=ctx)
        if ctx.enabled:
            out.mkdir(parents=True, exist_ok=True)
            (out / f"weights_rank{ctx.rank}.sha256").write_text(weights_hash(result.policy) + "\n")
        if not ctx.is_main:
            return None
        summary = {
            "iterations": result.iterations,
            "best_iteration": result.best_iteration,
            "restarts": result.restarts,
            "candidates": result.candidates,
            "best": result.best_metrics,
            "last": result.last_metrics,
            "frames": result.frames,
            "train_seconds": result.train_seconds,
            "world_size": ctx.world_size,
        }
        atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, sort_keys=True))
        _record_idle(out, data.facts)
        return summary
    finally:
        shutdown(ctx)
