"""Ship a trained checkpoint inside the package (``ompn_ros/checkpoints/``) with its provenance."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ompn_ros.checkpoints import HERE, SHIPPED
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint


def ship(domain: str, checkpoint: Path, provenance: dict[str, Any]) -> Path:
    """Copy ``checkpoint`` into the package as the shipped one, weights stored in float16 (half the size)."""
    target = HERE / SHIPPED[domain]
    policy, _ = load_checkpoint(checkpoint)
    save_checkpoint(target, policy, extra={"provenance": provenance}, weights_dtype="float16")
    (target / "provenance.json").write_text(json.dumps(provenance, indent=1, sort_keys=True) + "\n")
    return target
