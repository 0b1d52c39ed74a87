"""Build the policy module and its streaming stepper named by ``OMPNConfig.arch``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

from ompn_ros.model.config import ConfigError, OMPNConfig
from ompn_ros.model.lstm import LSTMPolicy, LSTMStreamingPolicy
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.model.streaming import Backend, StreamingPolicy

if TYPE_CHECKING:  # ensemble imports checkpoint, which imports this module
    from ompn_ros.model.ensemble import EnsembleStepper

PolicyModule: TypeAlias = OMPNPolicy | LSTMPolicy
"""Any trainable policy: ``forward_sequence``, ``set_obs_normalization``, ``config``."""
Stepper: TypeAlias = "StreamingPolicy | LSTMStreamingPolicy | EnsembleStepper"
"""Any batch-1 stepper: ``reset(sketch)``, ``step(obs) -> StepOutput``, ``config``."""


def build_policy(config: OMPNConfig) -> PolicyModule:
    """A freshly initialised policy of ``config.arch`` ('ompn' -> OMPNPolicy, 'lstm' -> LSTMPolicy)."""
    if config.arch == "ompn":
        return OMPNPolicy(config)
    if config.arch == "lstm":
        return LSTMPolicy(config)
    raise ConfigError(f"OMPNConfig.arch must be 'ompn' or 'lstm', got {config.arch!r}")


def build_stepper(policy: PolicyModule, backend: Backend = "jit") -> Stepper:
    """The streaming stepper of ``policy`` (compiled OMPN stepper, or the LSTM's stepper).

    The LSTM has no compiled kernel: ``'jit'`` selects its numpy path.
    """
    if isinstance(policy, LSTMPolicy):
        return LSTMStreamingPolicy(policy, backend="numpy" if backend == "jit" else backend)
    return StreamingPolicy(policy, backend=backend)


def stepper_from_checkpoint(path: str | Path, backend: Backend = "jit") -> Stepper:
    """Load a checkpoint of either architecture, or an ensemble directory (``ensemble.json``, see
    :mod:`ompn_ros.model.ensemble`), and wrap it in its streaming stepper."""
    from ompn_ros.model.checkpoint import load_checkpoint
    from ompn_ros.model.ensemble import EnsembleStepper, is_ensemble, read_ensemble

    if is_ensemble(path):
        members, _ = read_ensemble(path)
        steppers = [build_stepper(load_checkpoint(m)[0], backend=backend) for m in members]
        return EnsembleStepper(steppers, names=[str(m) for m in members])
    policy, _ = load_checkpoint(path)
    return build_stepper(policy, backend=backend)


__all__ = ["PolicyModule", "Stepper", "build_policy", "build_stepper", "stepper_from_checkpoint"]
