"""Offline behaviour-cloning training of the OMPN (single process or DDP under torchrun)."""

from typing import TYPE_CHECKING

from ompn_ros.lazy import lazy_names

if TYPE_CHECKING:  # the names below load on first use (PEP 562): importing a submodule stays light
    from ompn_ros.train.config import TrainConfig
    from ompn_ros.train.errors import TrainConfigError, TrainDataError
    from ompn_ros.train.evaluation import decomposition_metrics, evaluate
    from ompn_ros.train.trainer import TrainResult, train


_LAZY = {
    "TrainConfig": "ompn_ros.train.config",
    "TrainConfigError": "ompn_ros.train.errors",
    "TrainDataError": "ompn_ros.train.errors",
    "decomposition_metrics": "ompn_ros.train.evaluation",
    "evaluate": "ompn_ros.train.evaluation",
    "TrainResult": "ompn_ros.train.trainer",
    "train": "ompn_ros.train.trainer",
}

__all__ = [
    "TrainConfig",
    "TrainConfigError",
    "TrainDataError",
    "TrainResult",
    "decomposition_metrics",
    "evaluate",
    "train",
]


__getattr__ = lazy_names(__name__, globals(), _LAZY)
