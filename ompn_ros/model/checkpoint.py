"""Checkpoints: a directory with ``model.safetensors``, ``config.json`` and ``meta.json``.

* ``model.safetensors``: every parameter and buffer (including the observation normalisation).
* ``config.json``: :meth:`OMPNConfig.to_dict` (carries the config version).
* ``meta.json``: ``{"format_version": 1, "extra": {...}}``, e.g. training arguments and metrics, and
  ``"weights_dtype": "float16"`` when the weights were stored in half precision to keep a shipped
  checkpoint small; they are cast back to float32 on load (the model always computes in float32).

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
from ompn_ros.model.factory import PolicyModule, build_policy

CHECKPOINT_FORMAT_VERSION = 1
STORED_DTYPES = {"float32": torch.float32, "float16": torch.float16}
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
META_FILE = "meta.json"


class CheckpointError(RuntimeError):
    """A checkpoint cannot be written or read; the message names the file and the problem."""


def save_checkpoint(
    path: str | Path,
    policy: PolicyModule,
    *,
    extra: dict[str, Any] | None = None,
    weights_dtype: str = "float32",
) -> None:
    """Write ``policy`` (weights, buffers, config) and JSON-serializable ``extra`` to directory ``path``.

    ``weights_dtype='float16'`` halves the file (for shipped checkpoints); loading casts back to float32.
    """
    path = Path(path)
    if weights_dtype not in STORED_DTYPES:
        raise CheckpointError(
            f"{path}: weights_dtype must be one of {sorted(STORED_DTYPES)}, got {weights_dtype!r}"
        )
    meta = {"format_version": CHECKPOINT_FORMAT_VERSION, "extra": extra or {}, "weights_dtype": weights_dtype}
    try:
        meta_text = json.dumps(meta, indent=2)
    except TypeError as exc:
        raise CheckpointError(f"{path / META_FILE}: extra metadata is not JSON-serializable: {exc}") from exc
    stored = STORED_DTYPES[weights_dtype]
    tensors = {
        k: v.detach().to("cpu", dtype=stored if v.is_floating_point() else v.dtype).contiguous().clone()
        for k, v in policy.state_dict().items()
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        save_file(tensors, str(tmp / WEIGHTS_FILE), metadata={"format": "ompn_ros"})
        (tmp / CONFIG_FILE).write_text(policy.config.to_json())
        (tmp / META_FILE).write_text(meta_text)
        # mkdtemp creates 0700: make the checkpoint readable like any other installed data file.
        tmp.chmod(0o755)
        for file in tmp.iterdir():
            file.chmod(0o644)
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


def load_checkpoint(path: str | Path) -> tuple[PolicyModule, dict[str, Any]]:
    """Load a checkpoint directory; returns ``(policy in eval mode, extra metadata)``.

    The module class follows ``config.json``'s ``arch`` (``'ompn'`` or ``'lstm'``, see ``factory.py``).
    """
    path = Path(path)
    if not path.is_dir():
        raise CheckpointError(f"{path}: checkpoint directory does not exist")
    config = load_config(path)
    meta_file = path / META_FILE
    extra: dict[str, Any] = {}
    stored = torch.float32
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
        stored_name = meta.get("weights_dtype", "float32")
        if stored_name not in STORED_DTYPES:
            raise CheckpointError(
                f"{meta_file}: weights_dtype {stored_name!r} is not one of {sorted(STORED_DTYPES)}"
            )
        stored = STORED_DTYPES[stored_name]
    weights_file = path / WEIGHTS_FILE
    if not weights_file.is_file():
        raise CheckpointError(f"{weights_file}: missing")
    try:
        tensors = load_file(str(weights_file))
    except (SafetensorError, OSError, ValueError) as exc:
        raise CheckpointError(f"{weights_file}: not a readable safetensors file: {exc}") from exc
    policy = build_policy(config)
    expected = policy.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    if missing or unexpected:
        raise CheckpointError(
            f"{weights_file}: tensors do not match the config in {CONFIG_FILE}: missing {missing}, "
            f"unexpected {unexpected}"
        )
    for name, value in expected.items():
        if value.is_floating_point() and tensors[name].dtype == stored:
            tensors[name] = tensors[name].to(value.dtype)  # half-precision storage, float32 compute
        if tensors[name].shape != value.shape or tensors[name].dtype != value.dtype:
            raise CheckpointError(
                f"{weights_file}: tensor '{name}' has shape {tuple(tensors[name].shape)} "
                f"{tensors[name].dtype}, the config needs {tuple(value.shape)} {value.dtype}"
            )
    with torch.no_grad():
        policy.load_state_dict(tensors, strict=True)
    policy.eval()
    return policy, extra
