"""Pretrained checkpoints shipped as package data (safetensors + JSON), one directory each.

Each directory holds ``model.safetensors``, ``config.json`` and ``provenance.json`` (the command
line, seed and data that produced it, plus its held-out metrics).
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
SHIPPED = {"dial": "dial", "craft": "craft"}  # Dial no-sketch; Craft full observation, no sketch


class MissingCheckpointError(FileNotFoundError):
    """No shipped checkpoint exists for the requested domain."""


def shipped_checkpoint(domain: str) -> Path:
    """Directory of the shipped checkpoint for ``domain`` ('dial' or 'craft')."""
    if domain not in SHIPPED:
        raise MissingCheckpointError(f"no shipped checkpoint for domain '{domain}'; known: {sorted(SHIPPED)}")
    path = HERE / SHIPPED[domain]
    if not (path / "config.json").is_file():
        raise MissingCheckpointError(
            f"the shipped checkpoint for '{domain}' is missing at {path}; "
            f"rebuild it with `make reproduce-{domain}`"
        )
    return path
