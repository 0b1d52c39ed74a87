"""``ompn_train``: behaviour-clone an OMPN from rosbag2 recordings (or synthetic data).

Usage::

    ompn_train --bags BAG [BAG ...] --config config/train_dial.yaml --out DIR [--resume] [--set k=v ...]
    ompn_train --synthetic discrete --config config/train_craft.yaml --out DIR --set train.iterations=50
    torchrun --nproc_per_node=2 -m ompn_ros.cli.train --synthetic discrete --out DIR ...

The YAML config has three sections::

    model: {n_slots: 3, slot_size: 128, sketch_mode: none, memory_update: paper, ...}   # OMPNConfig
    train: {lr: 0.001, batch_size: 256, clip_norm: 0.2, bptt: 64, ...}                  # TrainConfig
    data:  {domain: craft}        # craft | dial: fixes obs_dim/action_type/action_dim from the layout

``obs_dim``, ``action_type`` and ``action_dim`` come from ``data.domain`` (``ompn_ros.layout``) or,
for ``--synthetic``, from the synthetic task; ``--set section.key=value`` overrides any entry (values
are parsed as YAML).  ``--out`` sets ``train.out_dir``; ``--resume`` sets ``train.resume``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import sys
from pathlib import Path
from typing import Any

import yaml

from ompn_ros.layout import DOMAINS

SECTIONS = ("model", "train", "data")
LOG = logging.getLogger("ompn_ros.cli.train")


class TrainCliError(ValueError):
    """A bad command line or config file (names the option or key at fault)."""


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
    except OSError as exc:
        raise TrainCliError(f"cannot read config file {path}: {exc}") from exc
    except yaml.YAMLError as exc:
        raise TrainCliError(f"config file {path} is not valid YAML: {exc}") from exc
    if not isinstance(raw, dict):
        raise TrainCliError(f"config file {path} must hold a mapping with sections {SECTIONS}")
    for key, value in raw.items():
        if key not in SECTIONS:
            raise TrainCliError(f"config file {path}: unknown section '{key}' (expected {SECTIONS})")
        if not isinstance(value, dict):
            raise TrainCliError(f"config file {path}: section '{key}' must be a mapping")
        config[key].update({k: _number_or_text(v) for k, v in value.items()})
    return config


def apply_overrides(config: dict[str, dict[str, Any]], overrides: list[str]) -> None:
    """Apply ``section.key=value`` overrides (value parsed as YAML) in place."""
    for item in overrides:
        if "=" not in item:
            raise TrainCliError(f"--set {item!r}: expected section.key=value")
        dotted, text = item.split("=", 1)
        if "." not in dotted:
            raise TrainCliError(f"--set {item!r}: key must be section.key with section in {SECTIONS}")
        section, key = dotted.split(".", 1)
        if section not in SECTIONS:
            raise TrainCliError(f"--set {item!r}: unknown section '{section}' (expected {SECTIONS})")
        try:
            config[section][key] = _number_or_text(yaml.safe_load(text))
        except yaml.YAMLError as exc:
            raise TrainCliError(f"--set {item!r}: value is not valid YAML: {exc}") from exc


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ompn_train", description=__doc__.split("\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--bags", nargs="+", metavar="PATH", help="rosbag2 directories or files to read")
    source.add_argument(
        "--synthetic",
        choices=("discrete", "continuous", "craft_shaped"),
        help="train on a synthetic task instead of bags (smoke runs)",
    )
    parser.add_argument("--episodes", type=int, default=200, help="synthetic episodes to generate")
    parser.add_argument("--config", help="YAML config (sections model/train/data)")
    parser.add_argument("--out", required=True, help="output directory (checkpoints, logs)")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/train_state")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config entry, e.g. --set train.lr=5e-4 (repeatable)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar, warnings only")
    return parser


def _load_episodes(args: argparse.Namespace, data: dict[str, Any]) -> tuple[list[Any], dict[str, Any]]:
    """Episodes plus the data-derived model fields (obs_dim, action_type, action_dim)."""
    if args.synthetic:
        from ompn_ros.train.synthetic import make_dataset, synthetic_spec

        seed = int(data.get("synthetic_seed", 0))
        episodes = make_dataset(args.synthetic, args.episodes, seed=seed)
        obs_dim, action_type, action_dim, vocab = synthetic_spec(args.synthetic)
        return episodes, {
            "obs_dim": obs_dim,
            "action_type": action_type,
            "action_dim": action_dim,
            "_vocab": vocab,
        }
    from ompn_ros.data.bag_reader import ReaderSpec
    from ompn_ros.data.cache import load_arrays

    domain_name = data.get("domain")
    spec_file = data.get("reader_spec")
    if spec_file:
        spec = ReaderSpec.from_yaml(spec_file)
    elif domain_name in DOMAINS:
        spec = ReaderSpec.for_domain(domain_name)
    else:
        raise TrainCliError(
            f"data.domain must be one of {sorted(DOMAINS)}, or give data.reader_spec (a reader YAML such as "
            f"config/reader_jointstate_example.yaml) for your own bags; got domain {domain_name!r}"
        )
    arrays = load_arrays(args.bags, spec=spec, on_error=data.get("on_error", "raise"),
                         use_cache=bool(data.get("cache", True)))
    episodes = arrays.episodes()
    if not episodes:
        raise TrainCliError(f"no episodes found in {args.bags}")
    if domain_name not in DOMAINS:
        return episodes, _fields_from_episodes(episodes, data)
    domain = DOMAINS[domain_name]
    return episodes, {
        "obs_dim": domain.obs_dim,
        "action_type": domain.action_type,
        "action_dim": domain.action_dim,
        "_vocab": domain.sketch_vocab,
    }


def _fields_from_episodes(episodes: list[Any], data: dict[str, Any]) -> dict[str, Any]:
    """Model sizes for a user's own bags: from the data, with ``data.action_dim`` for discrete actions."""
    first = episodes[0]
    continuous = first.actions.ndim == 2
    if continuous:
        action_dim = int(first.actions.shape[1])
    elif "action_dim" in data:
        action_dim = int(data["action_dim"])
    else:
        raise TrainCliError("discrete actions from your own bags need data.action_dim "
                            "(the number of actions, without 'done')")
    return {"obs_dim": int(first.observations.shape[1]),
            "action_type": "continuous" if continuous else "discrete", "action_dim": action_dim}


def weights_hash(policy: Any) -> str:
    """SHA-256 over the policy's state dict (names, shapes and raw bytes), for cross-rank checks."""
    digest = hashlib.sha256()
    for name, tensor in sorted(policy.state_dict().items()):
        digest.update(name.encode())
        digest.update(str(tuple(tensor.shape)).encode())
        digest.update(tensor.detach().contiguous().cpu().numpy().tobytes())
    return digest.hexdigest()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ompn_train`` console script; returns the process exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING if args.quiet else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
    )
    try:
        return _run(args)
    except (TrainCliError, ValueError, RuntimeError) as exc:
        print(f"ompn_train: error: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.train.distributed import init_distributed, shutdown
    from ompn_ros.train.trainer import TrainConfig, train

    config = load_config(args.config)
    apply_overrides(config, args.overrides)
    episodes, derived = _load_episodes(args, config["data"])
    vocab = derived.pop("_vocab", None)
    model_fields = {**config["model"], **derived}
    if model_fields.get("sketch_mode") == "sum" and not model_fields.get("sketch_vocab") and vocab:
        model_fields["sketch_vocab"] = vocab
    model_config = OMPNConfig.from_dict(model_fields)
    train_fields = {**config["train"], "out_dir": str(args.out), "resume": bool(args.resume)}
    if args.quiet:
        train_fields["progress"] = False
    train_config = TrainConfig.from_dict(train_fields)

    ctx = init_distributed()
    try:
        result = train(episodes, model_config, train_config, dist_ctx=ctx)
        out = Path(args.out)
        if ctx.enabled:
            out.mkdir(parents=True, exist_ok=True)
            (out / f"weights_rank{ctx.rank}.sha256").write_text(weights_hash(result.policy) + "\n")
        if ctx.is_main:
            summary = {
                "iterations": result.iterations,
                "best_iteration": result.best_iteration,
                "best": result.best_metrics,
                "last": result.last_metrics,
                "frames": result.frames,
                "train_seconds": result.train_seconds,
                "world_size": ctx.world_size,
            }
            (out / "summary.json").write_text(json.dumps(summary, indent=1, sort_keys=True))
            print(json.dumps({k: summary[k] for k in ("iterations", "best_iteration", "frames")}))
    finally:
        shutdown(ctx)
    return 0


if __name__ == "__main__":
    sys.exit(main())
