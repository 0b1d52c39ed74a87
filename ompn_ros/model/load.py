"""Path -> stepper: the one entry point that turns a checkpoint on disk into something that steps.

* :func:`load_checkpoint` (re-exported from ``checkpoint.py``): a checkpoint directory -> the policy
  module of its ``arch`` and its ``extra`` metadata.
* :func:`build_stepper`: a policy module -> its batch-1 streaming stepper.
* :func:`stepper_from_checkpoint`: a checkpoint directory *or* an ensemble directory
  (``ensemble.json``, see :mod:`ompn_ros.model.ensemble`) -> its stepper.
* :func:`shipped_stepper`: the stepper of the checkpoint shipped for a domain ('craft' or 'dial').

Every function here ends in :func:`load_checkpoint`, which reads the files (``checkpoint.py``) and
builds the module from its config (``build.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeAlias

import torch

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.model.build import PolicyModule
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.ensemble import EnsembleStepper, is_ensemble, read_ensemble
from ompn_ros.model.errors import StreamingInputError
from ompn_ros.model.lstm import LSTMPolicy, LSTMStreamingPolicy
from ompn_ros.model.streaming import Backend, StreamingPolicy

Stepper: TypeAlias = StreamingPolicy | LSTMStreamingPolicy | EnsembleStepper
"""Any batch-1 stepper: ``reset(sketch)``, ``step(obs) -> StepOutput``, ``config``."""


def build_stepper(
    policy: PolicyModule, backend: Backend = "jit", device: torch.device | str = "cpu"
) -> StreamingPolicy | LSTMStreamingPolicy:
    """The streaming stepper of ``policy`` (compiled OMPN stepper, or the LSTM's stepper).

    ``backend`` picks the OMPN stepper's kernel; the LSTM has one, torch, whatever ``backend``.
    ``device`` (default CPU) is where the OMPN ``'torch'`` backend steps; the LSTM's stepper runs on
    the CPU only.
    """
    if isinstance(policy, LSTMPolicy):
        if torch.device(device).type != "cpu":
            raise StreamingInputError(f"the LSTM stepper runs on the CPU only, not on {device}: use the CPU")
        return LSTMStreamingPolicy(policy, backend="torch")
    return StreamingPolicy(policy, backend=backend, device=device)


def stepper_from_checkpoint(
    path: str | Path, backend: Backend = "jit", device: torch.device | str = "cpu"
) -> Stepper:
    """Load a checkpoint of either architecture, or an ensemble directory, and wrap it in its stepper.

    Raises :class:`~ompn_ros.model.errors.CheckpointError` (or its subclass ``EnsembleError``)
    naming the file at fault.
    """
    if is_ensemble(path):
        members, _ = read_ensemble(path)
        steppers = [build_stepper(load_checkpoint(m)[0], backend=backend, device=device) for m in members]
        return EnsembleStepper(steppers, names=[str(m) for m in members])
    policy, _ = load_checkpoint(path)
    return build_stepper(policy, backend=backend, device=device)


def shipped_stepper(domain: str, backend: Backend = "jit") -> Stepper:
    """The stepper of the checkpoint shipped for ``domain`` ('craft' or 'dial').

    Raises :class:`~ompn_ros.checkpoints.MissingCheckpointError` for an unknown domain or a missing
    checkpoint.
    """
    return stepper_from_checkpoint(shipped_checkpoint(domain), backend=backend)


__all__ = ["Stepper", "build_stepper", "load_checkpoint", "shipped_stepper", "stepper_from_checkpoint"]
