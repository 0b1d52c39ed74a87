"""The body of ``ompn_ensemble``: an ensemble checkpoint directory and its starting detector settings.

The directory holds ensemble.json (:func:`ompn_ros.model.ensemble.write_ensemble`) and starts with
the first member's detector settings (detector.json); ``ompn_segment --tune --write-config`` on
labelled episodes none of the members was trained on replaces them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ompn_ros.detect.settings import load_detector_settings, save_detector_settings
from ompn_ros.model.checkpoint import load_config
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.ensemble import write_ensemble


def write_ensemble_dir(out: Path, members: Sequence[Path], meta: dict[str, Any]) -> tuple[Path, OMPNConfig]:
    """Write the ensemble of ``members`` into ``out`` with the first member's detector settings; returns
    the written file and the first member's model config (the members share it)."""
    target = write_ensemble(out, members, meta)
    first = load_detector_settings(members[0])
    save_detector_settings(out, dataclasses.replace(
        first, provenance=f"first member's settings ({members[0]}); tune the ensemble with "
        "ompn_segment --tune --write-config"))
    return target, load_config(members[0])
