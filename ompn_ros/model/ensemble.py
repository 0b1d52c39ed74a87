"""Ensembles of checkpoints: several streaming steppers stepped side by side, their outputs averaged.

An ensemble checkpoint is a directory that holds ``ensemble.json`` (no weights of its own)::

    {"format": "ompn_ros.ensemble", "format_version": 1,
     "members": ["../full_nosketch_seed0/best", "../full_nosketch_seed0_m1/best"], "extra": {}}

Member paths are relative to that directory (or absolute); each member is an ordinary checkpoint
(safetensors + JSON).  The members must agree on everything a consumer of the stepper sees:
``obs_dim``, ``n_slots``, ``action_type``, ``action_dim``, ``sketch_mode`` and ``sketch_vocab``.

One ensemble step feeds the same observation to every member and returns

* ``p_hat`` = the mean of the members' ``p_hat`` (so ``pi_end`` is their mean ``pi_end``) — the
  quantity the offline ensembles of ``python -m lab.reproduce --members`` average;
* ``pi`` = the slot part of that ``p_hat`` renormalised (lowest slot first);
* discrete actions: the argmax of the members' mean action distribution (softmax of each member's
  env-action logits); continuous: the mean of the members' Gaussian means.

This is not in the paper: each member is an OMPN (or LSTM) trained as the paper trains it, from its
own initialisation.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.model.checkpoint import load_config
from ompn_ros.model.checkpoint_json import read_checkpoint_json
from ompn_ros.model.errors import EnsembleError, StreamingInputError
from ompn_ros.model.step_output import StepOutput, checked_observation

ENSEMBLE_FILE = "ensemble.json"
ENSEMBLE_FORMAT = "ompn_ros.ensemble"
ENSEMBLE_FORMAT_VERSION = 1
SHARED_FIELDS = ("obs_dim", "n_slots", "action_type", "action_dim", "sketch_mode", "sketch_vocab")
"""Config fields every member of an ensemble must share."""


def is_ensemble(path: str | Path) -> bool:
    """True when ``path`` is an ensemble checkpoint directory (it holds ``ensemble.json``)."""
    return (Path(path) / ENSEMBLE_FILE).is_file()


def _check_members_agree(configs: Sequence[Any], names: Sequence[str]) -> None:
    first = configs[0]
    for config, name in zip(configs[1:], names[1:], strict=True):
        for field in SHARED_FIELDS:
            if getattr(config, field) != getattr(first, field):
                raise EnsembleError(
                    f"ensemble member {name} has {field}={getattr(config, field)!r}, but member "
                    f"{names[0]} has {getattr(first, field)!r}: all members must share "
                    f"{', '.join(SHARED_FIELDS)}"
                )


def write_ensemble(
    path: str | Path, members: Sequence[str | Path], extra: dict[str, Any] | None = None
) -> Path:
    """Write ``path/ensemble.json`` naming ``members`` (stored relative to ``path``); returns the file.

    Every member must be a loadable checkpoint configuration, and the members must agree on
    ``SHARED_FIELDS``; nothing is written otherwise.
    """
    root = Path(path)
    if len(members) < 2:
        raise EnsembleError(f"{root}: an ensemble needs at least 2 member checkpoints, got {len(members)}")
    configs = [load_config(m) for m in members]
    _check_members_agree(configs, [str(m) for m in members])
    root.mkdir(parents=True, exist_ok=True)
    doc = {
        "format": ENSEMBLE_FORMAT,
        "format_version": ENSEMBLE_FORMAT_VERSION,
        "members": [os.path.relpath(Path(m).resolve(), root.resolve()) for m in members],
        "extra": extra or {},
    }
    target = root / ENSEMBLE_FILE
    target.write_text(json.dumps(doc, indent=1) + "\n")
    return target


def read_ensemble(path: str | Path) -> tuple[list[Path], dict[str, Any]]:
    """The member checkpoint directories of the ensemble at ``path`` and its ``extra`` metadata."""
    file = Path(path) / ENSEMBLE_FILE
    doc = read_checkpoint_json(file, EnsembleError)
    if not isinstance(doc, dict) or doc.get("format") != ENSEMBLE_FORMAT:
        raise EnsembleError(f"{file}: 'format' must be {ENSEMBLE_FORMAT!r}")
    if doc.get("format_version") != ENSEMBLE_FORMAT_VERSION:
        raise EnsembleError(
            f"{file}: format_version {doc.get('format_version')!r} is not supported "
            f"(expected {ENSEMBLE_FORMAT_VERSION})"
        )
    members = doc.get("members")
    if not isinstance(members, list) or len(members) < 2 or not all(isinstance(m, str) for m in members):
        raise EnsembleError(f"{file}: 'members' must be a list of at least 2 checkpoint paths")
    resolved = [(Path(path) / m) if not Path(m).is_absolute() else Path(m) for m in members]
    for given, member in zip(members, resolved, strict=True):
        if not member.is_dir():
            raise EnsembleError(f"{file}: member '{given}' is not a checkpoint directory ({member})")
    extra = doc.get("extra", {})
    return resolved, extra if isinstance(extra, dict) else {}


def _softmax(logits: np.ndarray) -> np.ndarray:
    shifted = np.exp(logits - logits.max())
    return shifted / shifted.sum()


class EnsembleStepper:
    """Batch-1 stepper over several member steppers (``reset(sketch)``, ``step(obs)``, ``config``)."""

    def __init__(self, members: Sequence[Any], names: Sequence[str] | None = None) -> None:
        if len(members) < 2:
            raise EnsembleError(f"an ensemble needs at least 2 members, got {len(members)}")
        labels = list(names) if names is not None else [f"#{i}" for i in range(len(members))]
        _check_members_agree([m.config for m in members], labels)
        self.members = list(members)
        self.config = self.members[0].config
        self._steps = [getattr(m, "step_trusted", m.step) for m in self.members]
        self._ready = self.config.sketch_mode == "none"
        self._positions = np.arange(1, self.config.n_slots + 1, dtype=np.float32)

    def reset(self, sketch: np.ndarray | None = None) -> None:
        """Start a new episode in every member."""
        for member in self.members:
            member.reset(sketch)
        self._ready = True

    def step(self, obs: np.ndarray) -> StepOutput:
        """One observation through every member; the outputs averaged (see the module docstring)."""
        return self.step_trusted(checked_observation(obs, self.config.obs_dim, self._ready))

    def step_trusted(self, arr: np.ndarray) -> StepOutput:
        """:meth:`step` on an observation already checked by the caller (float32 ``[obs_dim]``)."""
        outs = [step(arr) for step in self._steps]
        # plain loops over the few members: cheaper than stacking small arrays on every step
        p_hat = np.array(outs[0].p_hat, dtype=np.float64)
        for out in outs[1:]:
            p_hat += out.p_hat
        p_hat /= len(outs)
        pi_end = float(p_hat[0])
        slots = p_hat[:0:-1]  # lowest slot first
        mass = float(slots.sum())
        pi = (slots / mass if mass > 0 else np.mean([o.pi for o in outs], axis=0)).astype(np.float32)
        logits: np.ndarray | None = None
        if self.config.action_type == "discrete":
            probs = np.zeros(self.config.action_dim, dtype=np.float64)
            for out in outs:
                if out.action_logits is None:
                    raise StreamingInputError("an ensemble member returned no action logits")
                probs += _softmax(np.asarray(out.action_logits, np.float64))
            probs /= len(outs)
            action: np.ndarray | int = int(probs.argmax())
            logits = np.log(np.maximum(probs, 1e-30)).astype(np.float32)
        else:
            mean = np.array(outs[0].action, dtype=np.float32)
            for out in outs[1:]:
                mean += out.action
            action = mean / np.float32(len(outs))
        return StepOutput(
            action=action,
            pi=pi,
            pi_end=pi_end,
            p_hat=p_hat.astype(np.float32),
            expected_position=float(pi @ self._positions),
            done_prob=pi_end,
            action_logits=logits,
        )


__all__ = [
    "ENSEMBLE_FILE",
    "EnsembleStepper",
    "is_ensemble",
    "read_ensemble",
    "write_ensemble",
]
