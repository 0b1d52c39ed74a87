"""Checkpoints: a directory with ``model.safetensors``, ``config.json`` and ``meta.json``.

* ``model.safetensors``: every parameter and buffer (including the observation normalisation).
* ``config.json``: :meth:`OMPNConfig.to_dict` (carries the config version).
* ``meta.json``: ``{"format_version": 1, "extra": {...}}``, e.g. training arguments and metrics.

Saving is atomic: the files go to a temporary sibling directory that replaces ``path`` with
``os.replace``.  Loading never unpickles anything.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from ompn_ros.model.config import ConfigError, OMPNConfig
from ompn_ros.model.policy import OMPNPolicy

CHECKPOINT_FORMAT_VERSION = 1
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
META_FILE = "meta.json"


class CheckpointError(RuntimeError):
    """A checkpoint cannot be written or read; the message names the file and the problem."""


def save_checkpoint(path: str | Path, policy: OMPNPolicy, *, extra: dict[str, Any] | None = None) -> None:
    """Write ``policy`` (weights, buffers, config) and JSON-serializable ``extra`` to directory ``path``."""
    path = Path(path)
    try:
        meta_text = json.dumps({"format_version": CHECKPOINT_FORMAT_VERSION, "extra": extra or {}}, indent=2)
    except TypeError as exc:
        raise CheckpointError(f"{path / META_FILE}: extra metadata is not JSON-serializable: {exc}") from exc
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in policy.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        save_file(tensors, str(tmp / WEIGHTS_FILE), metadata={"format": "ompn_ros"})
        (tmp / CONFIG_FILE).write_text(policy.config.to_json())
        (tmp / META_FILE).write_text(meta_text)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
            os.replace(path, old / "ckpt")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as exc:
        raise CheckpointError(f"{path}: cannot write checkpoint: {exc}") from exc
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def load_config(path: str | Path) -> OMPNConfig:
    """Read only the :class:`OMPNConfig` of checkpoint directory ``path``."""
    file = Path(path) / CONFIG_FILE
    if not file.is_file():
        raise CheckpointError(f"{file}: missing (is '{path}' an ompn_ros checkpoint directory?)")
    try:
        return OMPNConfig.from_json(file.read_text())
    except ConfigError as exc:
        raise CheckpointError(f"{file}: {exc}") from exc


def load_checkpoint(path: str | Path) -> tuple[OMPNPolicy, dict[str, Any]]:
    """Load a checkpoint directory; returns ``(policy in eval mode, extra metadata)``."""
    path = Path(path)
    if not path.is_dir():
        raise CheckpointError(f"{path}: checkpoint directory does not exist")
    config = load_config(path)
    meta_file = path / META_FILE
    extra: dict[str, Any] = {}
    if meta_file.is_file():
        try:
            meta = json.loads(meta_file.read_text())
        except json.JSONDecodeError as exc:
            raise CheckpointError(f"{meta_file}: not valid JSON: {exc}") from exc
        if meta.get("format_version") != CHECKPOINT_FORMAT_VERSION:
            raise CheckpointError(
                f"{meta_file}: checkpoint format_version {meta.get('format_version')!r} is not supported "
                f"(expected {CHECKPOINT_FORMAT_VERSION})"
            )
        extra = meta.get("extra", {})
    weights_file = path / WEIGHTS_FILE
    if not weights_file.is_file():
        raise CheckpointError(f"{weights_file}: missing")
    try:
        tensors = load_file(str(weights_file))
    except (SafetensorError, OSError, ValueError) as exc:
        raise CheckpointError(f"{weights_file}: not a readable safetensors file: {exc}") from exc
    policy = OMPNPolicy(config)
    expected = policy.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    if missing or unexpected:
        raise CheckpointError(
            f"{weights_file}: tensors do not match the config in {CONFIG_FILE}: missing {missing}, "
            f"unexpected {unexpected}"
        )
    for name, value in expected.items():
        if tensors[name].shape != value.shape or tensors[name].dtype != value.dtype:
            raise CheckpointError(
                f"{weights_file}: tensor '{name}' has shape {tuple(tensors[name].shape)} "
                f"{tensors[name].dtype}, the config needs {tuple(value.shape)} {value.dtype}"
            )
    with torch.no_grad():
        policy.load_state_dict(tensors, strict=True)
    policy.eval()
    return policy, extra
