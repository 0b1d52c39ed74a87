"""The OMPN model: config, cells, policy (training and streaming), loss and checkpoints."""

from ompn_ros.model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from ompn_ros.model.config import ConfigError, OMPNConfig
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
    "StreamingInputError",
    "StreamingPolicy",
    "bc_loss",
    "load_checkpoint",
    "save_checkpoint",
]
