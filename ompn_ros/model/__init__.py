"""The OMPN model: config, cells, policy (training and streaming), loss and checkpoints.

Loading has one path: ``build.py`` (config -> model), ``checkpoint.py`` (files <-> model) and
``load.py`` (path -> stepper: checkpoints, ensembles, the shipped checkpoint of a domain).
"""

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
