"""Ship a trained checkpoint inside the package (``ompn_ros/checkpoints/``) with its provenance."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from ompn_ros.checkpoints import HERE, SHIPPED
from ompn_ros.detect.settings import load_detector_settings, save_detector_settings
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint


def ship(domain: str, checkpoint: Path, provenance: dict[str, Any], chooser: str | None = None) -> Path:
    """Copy ``checkpoint`` into the package as the shipped one, weights stored in float16 (half the size).

    ``chooser`` names what chose the checkpoint's detector (a command and version) in its
    ``detector.json``; by default the checkpoint's path."""
    target = HERE / SHIPPED[domain]
    policy, _ = load_checkpoint(checkpoint)
    detector = load_detector_settings(checkpoint)  # read before save_checkpoint replaces the directory
    save_checkpoint(target, policy, extra={"provenance": provenance}, weights_dtype="float16")
    (target / "provenance.json").write_text(json.dumps(provenance, indent=1, sort_keys=True) + "\n")
    save_detector_settings(target, dataclasses.replace(
        detector, source="shipped",
        provenance=f"{detector.source} by {chooser or checkpoint}: {detector.provenance}"))
    return target
