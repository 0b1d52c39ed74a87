"""The one record of the final-observation choice: ``final_observation.json``.

``final_observation: auto`` (docs/design.md#final-observation-auto) reads the training bags once per
option and keeps one run.  Its choice is written in one format, by :func:`record_final` alone:

* beside each checkpoint it trained (``best/`` and ``last/`` of every run), ``chosen`` names the option
  that checkpoint was trained with; :func:`resolve_final` reads later bags of an ``auto`` spec with it,
  so a replay guesses row T as training did;
* in the output directory, when options were compared, the same record also holds the comparison
  (every option's validation figures, the objective and the rule that chose).

Without the record (a checkpoint trained on complete bags or with a fixed option), an ``auto`` spec
reads with its first option.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

from ompn_ros.app.errors import ReplayError
from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.reader import ReaderSpec
from ompn_ros.data.reader.spec import FINAL_GUESSES, FinalObservation
from ompn_ros.model.checkpoint_json import read_checkpoint_json

RECORD_FILE = "final_observation.json"
FORMAT = "ompn_ros.final_observation"


def record_final(directory: Path, option: str, comparison: Mapping[str, Any] | None = None) -> None:
    """Write ``directory/final_observation.json`` naming ``option`` (``chosen``), with ``comparison``'s
    entries when options were compared."""
    doc = {"format": FORMAT, "version": 1, "chosen": option, **(comparison or {})}
    atomic_write_text(directory / RECORD_FILE, json.dumps(doc, indent=1) + "\n")


def trained_final(checkpoint_dir: str | Path) -> FinalObservation | None:
    """The option recorded beside the checkpoint, or None when there is no record.

    Raises:
        ReplayError: the record is not this format or names no guessing option.
    """
    path = Path(checkpoint_dir) / RECORD_FILE
    if not path.exists() and not path.is_symlink():
        return None
    doc = read_checkpoint_json(path, ReplayError)
    option = doc.get("chosen") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or option not in FINAL_GUESSES:
        raise ReplayError(f"{path}: expected format {FORMAT!r} whose 'chosen' names one of "
                          f"{list(FINAL_GUESSES)}; retrain, or set final_observation to one option")
    return cast(FinalObservation, option)


def resolve_final(spec: ReaderSpec, checkpoint_dir: str | Path | None) -> ReaderSpec:
    """``spec`` with ``auto`` replaced by the option the checkpoint was trained with, even one outside
    the spec's ``final_options`` (unchanged for a fixed option, without a checkpoint, or without a
    record)."""
    if spec.final_observation != "auto" or checkpoint_dir is None:
        return spec
    option = trained_final(checkpoint_dir)
    return spec if option is None else replace(spec, final_observation=option)


__all__ = ["FORMAT", "RECORD_FILE", "record_final", "resolve_final", "trained_final"]
