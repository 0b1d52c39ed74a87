"""A small, nearly full filesystem for full-disk tests: a tmpfs mounted for the test and removed after.

Needs the right to mount (root, as in CI); elsewhere the test is skipped with the reason.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def small_disk(where: Path, size_kb: int = 1024, free_kb: int | None = None) -> Iterator[Path]:
    """A tmpfs of ``size_kb`` mounted at ``where`` (created), filled by a file ``filler`` until about
    ``free_kb`` are left (None: empty); unmounted and removed afterwards."""
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)],
                          capture_output=True, text=True, check=False)  # fmt: skip
    if done.returncode != 0:
        where.rmdir()
        pytest.skip(f"cannot mount a small tmpfs for the full-disk test: {done.stderr.strip()}")
    try:
        if free_kb is not None:
            (where / "filler").write_bytes(b"\0" * max(0, (size_kb - free_kb) * 1024))
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)
        where.rmdir()
