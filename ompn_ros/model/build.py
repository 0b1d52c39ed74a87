"""Config -> model: the policy module named by ``OMPNConfig.arch``, and its tensor shapes.

The one place that turns an :class:`OMPNConfig` into a module.  ``checkpoint.py`` uses
:func:`expected_tensors` to check a checkpoint's stored shapes before anything is allocated, and
``load.py`` wraps built modules in their streaming steppers.
"""

from __future__ import annotations

import math
from typing import TypeAlias

import torch

from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ConfigError, ModelSizeError
from ompn_ros.model.lstm import LSTMPolicy
from ompn_ros.model.policy import OMPNPolicy

PolicyModule: TypeAlias = OMPNPolicy | LSTMPolicy
"""Any trainable policy: ``forward_sequence``, ``set_obs_normalization``, ``config``."""
MAX_ELEMENTS = 1 << 28
"""Largest model we build (2^28 values, 1 GiB in float32; the paper's Craft model has 2.8 M)."""


def build_policy(config: OMPNConfig) -> PolicyModule:
    """A freshly initialised policy of ``config.arch`` ('ompn' -> OMPNPolicy, 'lstm' -> LSTMPolicy).

    Raises :class:`ModelSizeError` before allocating when the model would exceed ``MAX_ELEMENTS``.
    """
    check_model_size(config)
    return _construct(config)


def _construct(config: OMPNConfig) -> PolicyModule:
    if config.arch == "ompn":
        return OMPNPolicy(config)
    if config.arch == "lstm":
        return LSTMPolicy(config)
    raise ConfigError(f"OMPNConfig.arch must be 'ompn' or 'lstm', got {config.arch!r}")


def expected_tensors(config: OMPNConfig) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """Name -> ``(shape, dtype)`` of every tensor in the ``state_dict`` of ``build_policy(config)``.

    Built on PyTorch's ``meta`` device, so no memory is allocated whatever the sizes (O(#tensors)).
    """
    with torch.device("meta"):
        module = _construct(config)
    return {name: (tuple(t.shape), t.dtype) for name, t in module.state_dict().items()}


def check_model_size(config: OMPNConfig) -> int:
    """The number of values in the model of ``config``; :class:`ModelSizeError` above ``MAX_ELEMENTS``."""
    total = sum(math.prod(shape) for shape, _ in expected_tensors(config).values())
    if total > MAX_ELEMENTS:
        raise ModelSizeError(
            f"OMPNConfig describes a model of {total} values (obs_dim={config.obs_dim}, "
            f"n_slots={config.n_slots}, slot_size={config.slot_size}); the limit is {MAX_ELEMENTS}"
        )
    return total


__all__ = [
    "MAX_ELEMENTS",
    "PolicyModule",
    "build_policy",
    "check_model_size",
    "expected_tensors",
]
