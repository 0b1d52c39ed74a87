"""Hostile JSON in a checkpoint is one line naming the file, never a traceback: ``config.json``,
``meta.json`` and ``detector.json`` nested thousands of levels deep, in another encoding, replaced by
a FIFO, or huge; in the loaders, in ``ompn_segment`` (exit 2) and at ``ompn_node``'s start-up (exit 2)."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from ompn_ros import layout
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.errors import DetectorSettingsError
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.errors import OMPNError
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.errors import CheckpointError


def _deep(path: Path) -> None:
    path.write_text('{"a": ' + "[" * 100_000 + "]" * 100_000 + "}")


def _latin1(path: Path) -> None:
    path.write_bytes('{"note": "Zürich"}'.encode("latin-1"))


def _fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


MAX_JSON_BYTES = 16 * 1024 * 1024  # ompn_ros.model.checkpoint_json's limit


def _huge(path: Path) -> None:
    with open(path, "w") as handle:
        handle.write('{"pad": "')
        handle.truncate(MAX_JSON_BYTES + 10)


HOSTILE: dict[str, tuple[Callable[[Path], None], str]] = {
    "deep": (_deep, "levels deep"),
    "latin1": (_latin1, "not UTF-8"),
    "fifo": (_fifo, "not a regular file"),
    "huge": (_huge, "bytes"),
}


@pytest.fixture
def dial(tmp_path: Path) -> Path:
    ckpt = tmp_path / "dial"
    shutil.copytree(shipped_checkpoint("dial"), ckpt)
    return ckpt


@pytest.mark.parametrize("kind", sorted(HOSTILE))
@pytest.mark.parametrize("name", ["config.json", "meta.json", "detector.json"])
def test_each_checkpoint_json_is_refused_in_one_line(dial: Path, name: str, kind: str) -> None:
    spoil, words = HOSTILE[kind]
    spoil(dial / name)
    load: Callable[[Path], object] = load_detector_settings if name == "detector.json" else load_checkpoint
    expected: type[OMPNError] = DetectorSettingsError if name == "detector.json" else CheckpointError
    with pytest.raises(expected) as caught:
        load(dial)
    line = str(caught.value)
    assert str(dial / name) in line and words in line and "\n" not in line


def test_the_depth_ignores_brackets_inside_strings(tmp_path: Path) -> None:
    from ompn_ros.model.checkpoint_json import MAX_JSON_BYTES as limit
    from ompn_ros.model.checkpoint_json import json_depth, read_checkpoint_json

    assert limit == MAX_JSON_BYTES
    assert json_depth('{"a": "[[[[{{{{", "b": [1, {"c": "]]]"}]}') == 3
    file = tmp_path / "x.json"
    file.write_text('{"a": "' + "[" * 1000 + '"}')
    assert read_checkpoint_json(file) == {"a": "[" * 1000}


def test_ompn_segment_refuses_a_deep_config_with_exit_2(dial: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    from ompn_ros.cli.segment import main
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train import synthetic

    episodes = synthetic.make_dataset("discrete", 2, seed=3)
    domain = dataclasses.replace(layout.CRAFT, obs_dim=episodes[0].observations.shape[1])
    write_episodes(tmp_path / "bag", episodes, domain)
    _deep(dial / "config.json")
    assert main(["--bag", str(tmp_path / "bag"), "--checkpoint", str(dial),
                 "--out", str(tmp_path / "seg"), "--plot-episodes", "0"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "levels deep" in err and "config.json" in err


@pytest.mark.parametrize("name,spoil", [("detector.json", _latin1), ("meta.json", _deep)])
def test_ompn_node_start_up_is_one_line_and_exit_2(dial: Path, name: str, spoil: Callable[[Path], None],
                                                   ros_env: dict[str, str], tmp_path: Path) -> None:
    spoil(dial / name)
    from node_process import node_command

    done = subprocess.run(node_command(f"checkpoint:={dial}"), env=ros_env, cwd=tmp_path, capture_output=True,
                          text=True, timeout=240)
    problems = [x for x in (done.stdout + done.stderr).splitlines() if "[INFO]" not in x]
    assert done.returncode == 2, done.stdout + done.stderr
    assert len(problems) == 1 and problems[0].startswith("ompn_node: cannot start: "), problems
    assert str(dial / name) in problems[0]
