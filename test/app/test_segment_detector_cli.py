"""ompn_segment and the detector that travels with the checkpoint: --tune --write-config stores it,
a replay uses it, --detector-config overrides it, and the log says which settings run."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("torch")

from ompn_ros import layout
from ompn_ros.cli.segment import main
from ompn_ros.data.recorder.bag_writer import write_episodes
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.train import synthetic


@pytest.fixture
def setup(tmp_path: Path, synthetic_checkpoint: Path) -> tuple[Path, Path]:
    import dataclasses

    ckpt = tmp_path / "ckpt"
    shutil.copytree(synthetic_checkpoint, ckpt)
    (ckpt / "detector.json").unlink(missing_ok=True)
    episodes = synthetic.make_dataset("discrete", 6, seed=9)
    domain = dataclasses.replace(layout.CRAFT, obs_dim=episodes[0].observations.shape[1])
    write_episodes(tmp_path / "bag", episodes, domain)
    return ckpt, tmp_path / "bag"


def test_tune_writes_the_checkpoint_and_replay_uses_it(
    setup: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ckpt, bag = setup
    assert load_detector_settings(ckpt).source == "default"
    assert main(["--tune", "--bag", str(bag), "--checkpoint", str(ckpt),
                 "--write-config", str(tmp_path / "node.yaml")]) == 0
    best = json.loads(capsys.readouterr().out)["best"]
    stored = load_detector_settings(ckpt)
    assert stored.source == "tuned_on_validation" and stored.online.to_dict() == best
    assert (tmp_path / "node.yaml").is_file()

    assert main(["--bag", str(bag), "--checkpoint", str(ckpt), "--out", str(tmp_path / "seg"),
                 "--plot-episodes", "0"]) == 0
    captured = capsys.readouterr()
    assert "tuned_on_validation" in captured.err  # the log names the source
    assert json.loads(captured.out)["detector"] == best


def test_detector_config_overrides_the_checkpoint(
    setup: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ckpt, bag = setup
    yaml_file = tmp_path / "d.yaml"
    yaml_file.write_text("/**/ompn_node:\n  ros__parameters:\n    detector_high: 0.42\n")
    assert main(["--bag", str(bag), "--checkpoint", str(ckpt), "--out", str(tmp_path / "seg"),
                 "--plot-episodes", "0", "--detector-config", str(yaml_file)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["detector"]["high"] == 0.42
    assert "--detector-config" in captured.err
