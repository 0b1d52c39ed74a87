"""Checkpoints: a directory with ``model.safetensors``, ``config.json`` and ``meta.json``.

* ``model.safetensors``: every parameter and buffer (including the observation normalisation).
* ``config.json``: :meth:`OMPNConfig.to_dict` (carries the config version).
* ``meta.json``: ``{"format_version": 1, "extra": {...}}``, e.g. training arguments and metrics, and
  ``"weights_dtype": "float16"`` when the weights were stored in half precision to keep a shipped
  checkpoint small; they are cast back to float32 on load (the model always computes in float32).

Saving is atomic: the files go to a temporary sibling directory that replaces ``path`` with
``os.replace``; temporary directories left by a killed writer are removed by the next save.
Loading never unpickles anything, reads every JSON file with size, depth and encoding limits
(:mod:`ompn_ros.model.checkpoint_json`), and checks every stored tensor's name, dtype and shape (read from
the safetensors header) against the config before the model is allocated.

The module itself comes from :mod:`ompn_ros.model.build` (config -> model); streaming steppers and
ensembles from :mod:`ompn_ros.model.load` (path -> stepper).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file, save_file

from ompn_ros.atomic import free_space, make_temp_dir, remove_stale_temps, umask_mode
from ompn_ros.model.build import PolicyModule, build_policy, check_model_size, expected_tensors
from ompn_ros.model.checkpoint_json import read_checkpoint_json
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import CheckpointError, ConfigError

CHECKPOINT_FORMAT_VERSION = 1
STORED_DTYPES = {"float32": torch.float32, "float16": torch.float16}
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
META_FILE = "meta.json"
SAFETENSORS_DTYPES = {
    "F32": torch.float32, "F16": torch.float16, "BF16": torch.bfloat16, "F64": torch.float64,
    "I64": torch.int64, "I32": torch.int32, "I16": torch.int16, "I8": torch.int8, "U8": torch.uint8,
    "BOOL": torch.bool,
}
"""safetensors header dtype names -> torch dtypes."""


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
    remove_stale_temps(path.parent, path.name)
    tmp = make_temp_dir(path.parent, path.name)
    try:
        save_file(tensors, str(tmp / WEIGHTS_FILE), metadata={"format": "ompn_ros"})
        (tmp / CONFIG_FILE).write_text(policy.config.to_json())
        (tmp / META_FILE).write_text(meta_text)
        # mkdtemp creates 0700: the checkpoint gets the modes of any file the user writes (the umask)
        tmp.chmod(umask_mode(directory=True))
        for file in tmp.iterdir():
            file.chmod(umask_mode())
        if path.exists():
            old = make_temp_dir(path.parent, path.name, "old")
            os.replace(path, old / "ckpt")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except (OSError, SafetensorError) as exc:  # safetensors reports a full disk as its own error
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise CheckpointError(
            f"{path}: cannot write checkpoint: {reason} ({free_space(path.parent)}); the previous "
            "checkpoint, if any, is unchanged"
        ) from exc
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def load_config(path: str | Path) -> OMPNConfig:
    """Read only the :class:`OMPNConfig` of checkpoint directory ``path``."""
    file = Path(path) / CONFIG_FILE
    if not file.exists() and not file.is_symlink():  # anything else there is judged by the reader
        raise CheckpointError(f"{file}: missing (is '{path}' an ompn_ros checkpoint directory?)")
    try:
        return OMPNConfig.from_dict(read_checkpoint_json(file))
    except ConfigError as exc:
        raise CheckpointError(f"{file}: {exc}") from exc


def _read_meta(path: Path) -> tuple[dict[str, Any], torch.dtype]:
    """``(extra, stored float dtype)`` from ``meta.json`` (absent: ``({}, float32)``)."""
    meta_file = path / META_FILE
    if not meta_file.exists() and not meta_file.is_symlink():
        return {}, torch.float32
    meta = read_checkpoint_json(meta_file)
    if not isinstance(meta, dict) or meta.get("format_version") != CHECKPOINT_FORMAT_VERSION:
        version = meta.get("format_version") if isinstance(meta, dict) else None
        raise CheckpointError(
            f"{meta_file}: checkpoint format_version {version!r} is not supported "
            f"(expected {CHECKPOINT_FORMAT_VERSION})"
        )
    stored_name = meta.get("weights_dtype", "float32")
    if stored_name not in STORED_DTYPES:
        raise CheckpointError(
            f"{meta_file}: weights_dtype {stored_name!r} is not one of {sorted(STORED_DTYPES)}"
        )
    extra = meta.get("extra", {})
    return (extra if isinstance(extra, dict) else {}), STORED_DTYPES[stored_name]


def _check_header(weights_file: Path, config: OMPNConfig, stored: torch.dtype) -> None:
    """Compare the safetensors header (names, dtypes, shapes) with the model of ``config``.

    Reads only the header; neither the model nor the tensors are allocated.  O(#tensors).
    """
    expected = expected_tensors(config)
    try:
        with safe_open(str(weights_file), framework="pt") as handle:
            header = {k: (tuple(handle.get_slice(k).get_shape()), handle.get_slice(k).get_dtype())
                      for k in handle.keys()}
    except (SafetensorError, OSError, ValueError) as exc:
        raise CheckpointError(f"{weights_file}: not a readable safetensors file: {exc}") from exc
    missing = sorted(set(expected) - set(header))
    unexpected = sorted(set(header) - set(expected))
    if missing or unexpected:
        raise CheckpointError(
            f"{weights_file}: tensors do not match the config in {CONFIG_FILE}: missing {missing}, "
            f"unexpected {unexpected}"
        )
    for name, (shape, dtype) in expected.items():
        got_shape, got_dtype = header[name][0], SAFETENSORS_DTYPES.get(header[name][1], header[name][1])
        accepted = (dtype, stored) if dtype.is_floating_point else (dtype,)
        if got_shape != shape or got_dtype not in accepted:
            raise CheckpointError(
                f"{weights_file}: tensor '{name}' has shape {got_shape} {got_dtype}, "
                f"the config needs {shape} {accepted[-1]}"
            )


def load_checkpoint(path: str | Path) -> tuple[PolicyModule, dict[str, Any]]:
    """Load a checkpoint directory; returns ``(policy in eval mode, extra metadata)``.

    The module class follows ``config.json``'s ``arch`` (``'ompn'`` or ``'lstm'``, see ``build.py``).
    Sizes are bounded and the stored shapes checked before the model is allocated.
    """
    path = Path(path)
    if not path.is_dir():
        raise CheckpointError(f"{path}: checkpoint directory does not exist")
    config = load_config(path)
    extra, stored = _read_meta(path)
    weights_file = path / WEIGHTS_FILE
    if not weights_file.is_file():
        raise CheckpointError(f"{weights_file}: missing")
    try:
        check_model_size(config)
    except ConfigError as exc:
        raise CheckpointError(f"{path / CONFIG_FILE}: {exc}") from exc
    _check_header(weights_file, config, stored)
    try:
        tensors = load_file(str(weights_file))
    except (SafetensorError, OSError, ValueError) as exc:
        raise CheckpointError(f"{weights_file}: not a readable safetensors file: {exc}") from exc
    policy = build_policy(config)
    for name, value in policy.state_dict().items():
        if value.is_floating_point() and tensors[name].dtype != value.dtype:
            tensors[name] = tensors[name].to(value.dtype)  # half-precision storage, float32 compute
    with torch.no_grad():
        policy.load_state_dict(tensors, strict=True)
    policy.eval()
    return policy, extra


__all__ = [
    "CHECKPOINT_FORMAT_VERSION",
    "load_checkpoint",
    "load_config",
    "save_checkpoint",
]
