"""The OMPN model: config, cells, policy (training and streaming), loss and checkpoints.

Loading has one path: ``build.py`` (config -> model), ``checkpoint.py`` (files <-> model) and
``load.py`` (path -> stepper: checkpoints, ensembles, the shipped checkpoint of a domain).
"""

from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from ompn_ros.model.config import ConfigError, OMPNConfig
from ompn_ros.model.load import Stepper, build_stepper, shipped_stepper, stepper_from_checkpoint
from ompn_ros.model.loss import LossInputError, bc_loss
from ompn_ros.model.policy import (
    MemoryState,
    ModelInputError,
    OMPNPolicy,
    SequenceOutput,
    StepTensors,
)
from ompn_ros.model.streaming import StepOutput, StreamingInputError, StreamingPolicy

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
