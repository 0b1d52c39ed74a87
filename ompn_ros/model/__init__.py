"""The OMPN model: config, cells, policy (training and streaming), loss and checkpoints.

Loading has one path: ``build.py`` (config -> model), ``checkpoint.py`` (files <-> model) and
``load.py`` (path -> stepper: checkpoints, ensembles, the shipped checkpoint of a domain).
"""

from typing import TYPE_CHECKING

from ompn_ros.lazy import lazy_names

if TYPE_CHECKING:  # the names below load on first use (PEP 562): importing a submodule stays light
    from ompn_ros.model.build import build_policy
    from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.model.errors import (
        CheckpointError,
        ConfigError,
        LossInputError,
        ModelInputError,
        StreamingInputError,
    )
    from ompn_ros.model.load import Stepper, build_stepper, shipped_stepper, stepper_from_checkpoint
    from ompn_ros.model.loss import bc_loss
    from ompn_ros.model.policy import MemoryState, OMPNPolicy, SequenceOutput, StepTensors
    from ompn_ros.model.streaming import StepOutput, StreamingPolicy


_LAZY = {
    "build_policy": "ompn_ros.model.build",
    "load_checkpoint": "ompn_ros.model.checkpoint",
    "save_checkpoint": "ompn_ros.model.checkpoint",
    "OMPNConfig": "ompn_ros.model.config",
    "CheckpointError": "ompn_ros.model.errors",
    "ConfigError": "ompn_ros.model.errors",
    "LossInputError": "ompn_ros.model.errors",
    "ModelInputError": "ompn_ros.model.errors",
    "StreamingInputError": "ompn_ros.model.errors",
    "Stepper": "ompn_ros.model.load",
    "build_stepper": "ompn_ros.model.load",
    "shipped_stepper": "ompn_ros.model.load",
    "stepper_from_checkpoint": "ompn_ros.model.load",
    "bc_loss": "ompn_ros.model.loss",
    "MemoryState": "ompn_ros.model.policy",
    "OMPNPolicy": "ompn_ros.model.policy",
    "SequenceOutput": "ompn_ros.model.policy",
    "StepTensors": "ompn_ros.model.policy",
    "StepOutput": "ompn_ros.model.streaming",
    "StreamingPolicy": "ompn_ros.model.streaming",
}

__all__ = [
    "CheckpointError",
    "ConfigError",
    "LossInputError",
    "MemoryState",
    "ModelInputError",
    "OMPNConfig",
    "OMPNPolicy",
    "SequenceOutput",
    "StepOutput",
    "StepTensors",
    "Stepper",
    "StreamingInputError",
    "StreamingPolicy",
    "bc_loss",
    "build_policy",
    "build_stepper",
    "load_checkpoint",
    "save_checkpoint",
    "shipped_stepper",
    "stepper_from_checkpoint",
]


__getattr__ = lazy_names(__name__, globals(), _LAZY)
