"""Outputs follow the umask: tables, summaries, records, ``pi.npz``, ``detector.json`` and checkpoints
get the mode any file the user writes gets (they were written owner-only, 0600, whatever the umask)."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.atomic import atomic_write, atomic_write_text, current_umask, umask_mode


@pytest.fixture(params=[0o022, 0o002, 0o077])
def umask(request: pytest.FixtureRequest) -> Iterator[int]:
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_atomic_files_get_the_umask_mode(tmp_path: Path, umask: int) -> None:
    atomic_write_text(tmp_path / "summary.json", json.dumps({"bags": 3}))
    atomic_write(tmp_path / "pi.npz", lambda handle: np.savez_compressed(handle, pi=np.zeros(3)))
    assert current_umask() == umask
    for name in ("summary.json", "pi.npz"):
        assert _mode(tmp_path / name) == 0o666 & ~umask, name


def test_detector_json_and_checkpoint_follow_the_umask(tmp_path: Path, umask: int) -> None:
    from ompn_ros.detect.settings import DetectorSettings, save_detector_settings
    from ompn_ros.model.build import build_policy
    from ompn_ros.model.checkpoint import save_checkpoint
    from ompn_ros.model.config import OMPNConfig

    ckpt = tmp_path / "ckpt"
    save_checkpoint(ckpt, build_policy(OMPNConfig(obs_dim=4, action_type="discrete", action_dim=3,
                                                  n_slots=2, slot_size=8)))
    save_detector_settings(ckpt, DetectorSettings())
    assert _mode(ckpt) == umask_mode(directory=True) == 0o777 & ~umask
    for file in ckpt.iterdir():
        assert _mode(file) == 0o666 & ~umask, file.name


def test_a_command_under_umask_002_writes_group_writable_files(tmp_path: Path) -> None:
    """The same from a fresh process that sets its umask the way a shell does."""
    code = ("import os, json, pathlib; os.umask(0o002); from ompn_ros.atomic import atomic_write_text; "
            f"atomic_write_text(pathlib.Path({str(tmp_path)!r}) / 'table.csv', 'bag,segments\\n')")
    subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ), timeout=60)
    assert _mode(tmp_path / "table.csv") == 0o664
