"""Boundary heads for tests: a toy head and a checkpoint that carries one."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.head import (
    BoundaryHead,
)
from ompn_ros.detect.settings import load_detector_settings, save_detector_settings
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.train.boundary_head import choose_rule, train_head
from ompn_ros.train.evaluation import teacher_forced_outputs
from sim_nodes.registry import default_tasks, expert_episode

torch = pytest.importorskip("torch")


def _toy_head(window: int, features: int, lags: int) -> BoundaryHead:
    """A head whose lag-1 probability is high when the newest first feature is, else low."""
    width = window * features
    w0 = np.zeros((width, 3))
    w0[width - features, 0] = 1.0
    w2 = np.zeros((3, lags))
    w2[0, 1] = 4.0
    weights = ((w0, np.zeros(3)), (np.eye(3), np.zeros(3)), (w2, np.full(lags, -2.0)))
    return BoundaryHead(weights, np.zeros(width), np.ones(width), window, features)


def checkpoint_with_head(tmp_path: Path, domain: str) -> Path:
    """A copy of the shipped checkpoint whose detector is a head trained on a few expert episodes."""
    path = tmp_path / domain
    shutil.copytree(shipped_checkpoint(domain), path)
    policy, _ = load_checkpoint(path)
    tasks = default_tasks(domain)
    eps = [expert_episode(domain, 500 + i, task=tasks[i % len(tasks)]) for i in range(24)]
    outs = teacher_forced_outputs(policy, eps)  # type: ignore[arg-type]
    head = train_head(outs[:18], [ep.boundaries for ep in eps[:18]], seed=0, epochs=10)
    choice = choose_rule(head, outs[18:], eps[18:])
    stored = load_detector_settings(path)
    save_detector_settings(path, type(stored)(online=choice.config, head=choice.head, provenance="a test"))
    return path
