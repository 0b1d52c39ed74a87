"""The final-row guess a checkpoint was trained with, recorded beside it.

``final_observation: auto`` (docs/design.md#final-observation-auto) reads the training bags once per
option and keeps one run.  Its ``best/`` and ``last/`` then hold ``final_guess.json`` naming the
option kept, and :func:`resolve_final` reads later bags of an ``auto`` spec with that option for that
checkpoint, so a replay guesses row T as training did.  Without the record (a checkpoint trained on
complete bags or with a fixed option), an ``auto`` spec reads with its first option.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import cast

from ompn_ros.app.errors import ReplayError
from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.reader import ReaderSpec
from ompn_ros.data.reader.spec import FINAL_GUESSES, FinalObservation
from ompn_ros.model.checkpoint_json import read_checkpoint_json

RECORD_FILE = "final_guess.json"
FORMAT = "ompn_ros.final_guess"


def record_final(checkpoint_dir: Path, option: str) -> None:
    """Write ``checkpoint_dir/final_guess.json`` naming ``option``."""
    doc = {"format": FORMAT, "version": 1, "final_observation": option}
    atomic_write_text(checkpoint_dir / RECORD_FILE, json.dumps(doc, indent=1) + "\n")


def trained_final(checkpoint_dir: str | Path) -> FinalObservation | None:
    """The option recorded beside the checkpoint, or None when there is no record.

    Raises:
        ReplayError: the record is not this format or names no guessing option.
    """
    path = Path(checkpoint_dir) / RECORD_FILE
    if not path.exists() and not path.is_symlink():
        return None
    doc = read_checkpoint_json(path, ReplayError)
    option = doc.get("final_observation") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or option not in FINAL_GUESSES:
        raise ReplayError(f"{path}: expected format {FORMAT!r} naming one of {list(FINAL_GUESSES)}")
    return cast(FinalObservation, option)


def resolve_final(spec: ReaderSpec, checkpoint_dir: str | Path | None) -> ReaderSpec:
    """``spec`` with ``auto`` replaced by the option the checkpoint was trained with, even one outside
    the spec's ``final_options`` (unchanged for a fixed option, without a checkpoint, or without a
    record)."""
    if spec.final_observation != "auto" or checkpoint_dir is None:
        return spec
    option = trained_final(checkpoint_dir)
    return spec if option is None else replace(spec, final_observation=option)


__all__ = ["RECORD_FILE", "record_final", "resolve_final", "trained_final"]
