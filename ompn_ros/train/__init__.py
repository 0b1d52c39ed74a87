"""Offline behaviour-cloning training of the OMPN (single process or DDP under torchrun)."""

from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError, TrainDataError
from ompn_ros.train.evaluation import decomposition_metrics, evaluate
from ompn_ros.train.trainer import TrainResult, train

__all__ = [
    "TrainConfig",
    "TrainConfigError",
    "TrainDataError",
    "TrainResult",
    "decomposition_metrics",
    "evaluate",
    "train",
]
