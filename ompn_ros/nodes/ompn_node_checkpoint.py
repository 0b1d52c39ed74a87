"""``ompn_node``'s checkpoint: which one it loads and whether it fits the parameters (ROS-free).

Each check raises ``ValueError`` with the one line the configure transition fails with.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros import layout
from ompn_ros.checkpoints import MissingCheckpointError, shipped_checkpoint


def default_checkpoint(domain: str) -> Path | None:
    """The checkpoint shipped as package data for ``domain`` (``ompn_ros/checkpoints/<domain>``)."""
    try:
        return shipped_checkpoint(domain)
    except MissingCheckpointError:
        return None


def resolve_checkpoint(values: Mapping[str, Any]) -> str:
    """The ``checkpoint`` parameter, else the shipped checkpoint of ``domain``."""
    path, domain = str(values["checkpoint"]), str(values["domain"])
    if path:
        if not Path(path).is_dir():
            raise ValueError(f"checkpoint '{path}' is not a directory")
        return path
    if not domain:
        raise ValueError("no checkpoint: set the 'checkpoint' parameter or 'domain' for the shipped one")
    found = default_checkpoint(domain)
    if found is None:
        raise ValueError(f"no shipped checkpoint for domain '{domain}'; set the 'checkpoint' parameter")
    return str(found)


def check_model(values: Mapping[str, Any], config: Any) -> None:
    """The model ``config`` against ``domain``, ``obs_dim``, ``action_type`` and ``sketch_mode``."""
    domain = str(values["domain"])
    expected_dim = int(values["obs_dim"])
    expected_action = str(values["action_type"])
    if domain:
        dom = layout.DOMAINS[domain]
        if values["obs_source"] == "array" and not str(values["observation_spec"]).strip():
            expected_dim = expected_dim or dom.obs_dim
        expected_action = expected_action or dom.action_type
        if config.action_dim != dom.action_dim:
            raise ValueError(
                f"checkpoint action_dim={config.action_dim} does not fit domain '{domain}' "
                f"(action_dim={dom.action_dim})"
            )
    if expected_dim and config.obs_dim != expected_dim:
        raise ValueError(
            f"checkpoint obs_dim={config.obs_dim} does not match the expected observation size {expected_dim}"
        )
    if expected_action and config.action_type != expected_action:
        raise ValueError(
            f"checkpoint action_type='{config.action_type}' does not match the expected '{expected_action}'"
        )
    sketch_mode = str(values["sketch_mode"])
    if sketch_mode and config.sketch_mode != sketch_mode:
        raise ValueError(
            f"checkpoint sketch_mode='{config.sketch_mode}' does not match the expected '{sketch_mode}'"
        )


def default_sketch(values: Mapping[str, Any]) -> np.ndarray | None:
    """The ``sketch`` parameter as ids; ``None`` for ``[-1]`` (0 is a valid id and ROS cannot declare
    an empty integer array)."""
    ids = [int(v) for v in values["sketch"]]
    return np.asarray(ids, dtype=np.int64) if ids != [-1] else None
