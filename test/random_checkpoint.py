"""A checkpoint of a randomly initialised OMPN, for tests whose subject is not the weights."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch

from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.policy import OMPNPolicy


def random_checkpoint(factory: pytest.TempPathFactory, name: str, *, seed: int, **config: Any) -> Path:
    """Save ``OMPNPolicy(OMPNConfig(**config))`` initialised from ``seed`` under a new temporary
    folder ``name``; returns the checkpoint directory."""
    torch.manual_seed(seed)
    path = factory.mktemp(name) / "ckpt"
    save_checkpoint(path, OMPNPolicy(OMPNConfig(**config)))
    return path
