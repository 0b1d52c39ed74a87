"""Errors of the model package: configs, checkpoints and ensembles, model inputs, failed writes.

Every class derives from :class:`ompn_ros.errors.OMPNError`; the message names the file, field or
tensor at fault.
"""

from __future__ import annotations

from ompn_ros.errors import OMPNError


class CheckpointError(OMPNError, RuntimeError):
    """A checkpoint cannot be written or read; the message names the file and the problem."""


class EnsembleError(CheckpointError):
    """An ensemble manifest or its members cannot be used (names the file or member at fault)."""


class ConfigError(OMPNError, ValueError):
    """An invalid :class:`~ompn_ros.model.config.OMPNConfig` field or an unreadable serialized config."""


class ModelSizeError(ConfigError):
    """A config asks for a model larger than :data:`~ompn_ros.model.build.MAX_ELEMENTS` values."""


class ModelInputError(OMPNError, ValueError):
    """A tensor handed to the model has the wrong shape, dtype or content."""


class StreamingInputError(ModelInputError):
    """Bad input to :class:`~ompn_ros.model.streaming.StreamingPolicy` (wrong observation size,
    missing sketch, ...)."""


class LossInputError(OMPNError, ValueError):
    """Targets or masks passed to :func:`~ompn_ros.model.loss.bc_loss` do not match the model outputs."""
