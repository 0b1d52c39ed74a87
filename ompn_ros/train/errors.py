"""Errors of training: the training config, the episodes, the resumable state, the device, the
torchrun environment and distillation teachers.

Every class derives from :class:`ompn_ros.errors.OMPNError`; the message names what is at fault.
"""

from __future__ import annotations

from ompn_ros.errors import OMPNError


class TrainConfigError(OMPNError, ValueError):
    """An invalid :class:`~ompn_ros.train.config.TrainConfig` field."""


class TrainDataError(OMPNError, ValueError):
    """The episodes given to :func:`~ompn_ros.train.trainer.train` cannot be trained on."""


class BatchError(OMPNError, ValueError):
    """Episodes that cannot be collated (names the episode at fault)."""


class EvaluationError(OMPNError, ValueError):
    """Episodes or p_hat sequences that cannot be evaluated."""


class SyntheticError(OMPNError, ValueError):
    """Invalid parameters for a synthetic task generator."""


class TrainStateError(OMPNError, RuntimeError):
    """A training state on disk is missing, incomplete or incompatible."""


class DistributedError(OMPNError, RuntimeError):
    """The torchrun environment is inconsistent or the process group failed."""


class DeviceError(OMPNError, ValueError):
    """A device that does not exist here (one line naming the setting and the fix)."""


class DistillError(OMPNError, ValueError):
    """A teacher that cannot be used (names the checkpoint at fault)."""
