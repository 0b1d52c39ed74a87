"""Resumable training state on disk: model + Adam state (safetensors) + JSON, written atomically.

Layout under ``<out_dir>/train_state/``::

    LATEST                   JSON pointer {"dir": "it00000120"}, replaced atomically (os.replace)
    it00000120/model/        save_checkpoint() output (weights + config + extra)
    it00000120/optimizer.safetensors   every tensor of the optimizer state, key "state.<param>.<name>"
    it00000120/state.json    iteration, best record, history, optimizer param_groups

A state directory is complete before the pointer names it, so a kill at any moment leaves either the
previous or the new state readable.  Older state directories are removed after the pointer moves, and
temporaries left by a killed run (``.<name>.tmp-<pid>-*``) on every save and when training starts
(:func:`clean_state_root`).
No pickle is involved anywhere.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from ompn_ros.atomic import atomic_write_text, make_temp_dir, remove_stale_temps, write_failure
from ompn_ros.train.errors import TrainStateError

POINTER = "LATEST"
STATE_FORMAT = 1


def optimizer_to_files(
    optimizer: torch.optim.Optimizer,
) -> tuple[dict[str, torch.Tensor], list[dict[str, Any]]]:
    """Split an optimizer state dict into flat tensors and JSON-serialisable param groups."""
    sd = optimizer.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    for index, entries in sd["state"].items():
        for name, value in entries.items():
            if not isinstance(value, torch.Tensor):
                value = torch.tensor(value)
            tensors[f"state.{index}.{name}"] = value.detach().cpu().clone().contiguous()
    groups = [{k: (list(v) if isinstance(v, tuple) else v) for k, v in g.items()} for g in sd["param_groups"]]
    return tensors, groups


def optimizer_from_files(
    optimizer: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], groups: list[dict[str, Any]]
) -> None:
    """Inverse of :func:`optimizer_to_files`: load the state into ``optimizer``."""
    state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        _, index, name = key.split(".", 2)
        state.setdefault(int(index), {})[name] = value
    restored = [{k: (tuple(v) if k == "betas" else v) for k, v in g.items()} for g in groups]
    try:
        optimizer.load_state_dict({"state": state, "param_groups": restored})
    except (ValueError, KeyError) as exc:
        raise TrainStateError(f"optimizer state does not fit this model: {exc}") from exc


def save_state(
    root: Path,
    iteration: int,
    save_model: Any,
    optimizer: torch.optim.Optimizer,
    payload: dict[str, Any],
) -> Path:
    """Write a complete state directory for ``iteration`` and point ``LATEST`` at it.

    ``save_model(directory)`` writes the model checkpoint (``save_checkpoint`` bound to the policy).
    """
    clean_state_root(root)
    name = f"it{iteration:08d}"
    target = root / name
    tmp = make_temp_dir(root, name)
    try:
        save_model(tmp / "model")
        tensors, groups = optimizer_to_files(optimizer)
        save_file(tensors, str(tmp / "optimizer.safetensors"))
        doc = {"format": STATE_FORMAT, "iteration": iteration, "param_groups": groups, **payload}
        (tmp / "state.json").write_text(json.dumps(doc, indent=1, sort_keys=True), encoding="utf-8")
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except (OSError, SafetensorError) as exc:  # a full disk: one line naming the state directory
        shutil.rmtree(tmp, ignore_errors=True)
        raise write_failure(target, exc) from exc
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(root / POINTER, json.dumps({"dir": name}))
    for old in root.iterdir():
        if old.is_dir() and old.name != name and not old.name.startswith("."):
            shutil.rmtree(old, ignore_errors=True)
    return target


def clean_state_root(root: Path) -> list[Path]:
    """Remove the temporaries a killed run left in ``root`` (see :mod:`ompn_ros.atomic`)."""
    return remove_stale_temps(root)


def latest_state_dir(root: Path) -> Path | None:
    """The state directory ``LATEST`` points to, or None when no state was ever saved."""
    pointer = root / POINTER
    if not pointer.exists():
        return None
    try:
        name = json.loads(pointer.read_text(encoding="utf-8"))["dir"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise TrainStateError(f"{pointer} is not a valid state pointer: {exc}") from exc
    path = root / name
    if not (path / "state.json").exists() or not (path / "optimizer.safetensors").exists():
        raise TrainStateError(f"training state {path} named by {pointer} is incomplete")
    return path


def read_state(path: Path) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """``(state.json document, optimizer tensors)`` of a state directory."""
    try:
        doc = json.loads((path / "state.json").read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise TrainStateError(f"{path}/state.json is not valid JSON ({exc})") from exc
    if doc.get("format") != STATE_FORMAT:
        raise TrainStateError(f"{path}/state.json has format {doc.get('format')!r}, expected {STATE_FORMAT}")
    return doc, load_file(str(path / "optimizer.safetensors"))
