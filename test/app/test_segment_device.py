"""``ompn_segment --device auto|cpu|cuda``: the replay's torch backend on an explicit device."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from batch_bags import SPEC, write_lab_bag

from ompn_ros.app.replay import ReplayResult, replay_all
from ompn_ros.cli.segment import main
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import StreamingInputError
from ompn_ros.model.load import build_stepper, stepper_from_checkpoint
from ompn_ros.train.device import stray_tensors

CONFIG = OMPNConfig(obs_dim=4, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)
GPU = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no GPU")


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Two bags of another lab (rosbags writer), its reader spec and an untrained model."""
    root = tmp_path_factory.mktemp("lab")
    (root / "bags").mkdir()
    write_lab_bag(root / "bags" / "a", 1)
    write_lab_bag(root / "bags" / "b", 2)
    (root / "lab_reader.yaml").write_text(yaml.safe_dump(SPEC))
    torch.manual_seed(0)
    save_checkpoint(root / "model", build_policy(CONFIG))
    return {"bags": root / "bags", "spec": root / "lab_reader.yaml", "model": root / "model"}


def _replays(lab: dict, backend: str, device: str) -> list[ReplayResult]:
    episodes = read_episodes(lab["bags"] / "a", spec=ReaderSpec.from_yaml(lab["spec"])).episodes
    stepper = stepper_from_checkpoint(lab["model"], backend, device)  # type: ignore[arg-type]
    return replay_all(stepper, episodes, DetectorConfig())


def _assert_same(a: list[ReplayResult], b: list[ReplayResult], atol: float) -> None:
    assert len(a) == len(b) == 2
    for x, y in zip(a, b, strict=True):
        assert x.boundary_steps == y.boundary_steps
        np.testing.assert_allclose(x.pi, y.pi, atol=atol, rtol=0)


def test_the_torch_backend_on_an_explicit_cpu_matches_the_compiled_stepper(lab: dict) -> None:
    _assert_same(_replays(lab, "torch", "cpu"), _replays(lab, "jit", "cpu"), atol=1e-5)


@pytest.mark.parametrize("mode", ["--bag", "--bags"])
def test_cuda_without_a_gpu_is_one_line_before_any_bag_is_read(
    lab: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    bag = lab["bags"] / "a" if mode == "--bag" else lab["bags"]
    out = tmp_path / "out"
    code = main([mode, str(bag), "--device", "cuda", "--checkpoint", str(lab["model"]),
                 "--reader-config", str(lab["spec"]), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "--device=cuda" in err and "no GPU" in err and not out.exists()


def _table(out: Path) -> list[dict[str, str]]:
    with open(out / "segments.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@GPU
def test_the_cuda_replay_matches_the_cpu_replay(lab: dict, tmp_path: Path) -> None:
    stepper = stepper_from_checkpoint(lab["model"], "torch", "cuda")
    assert stray_tensors(stepper.policy, torch.device("cuda", 0)) == []  # type: ignore[union-attr]
    _assert_same(_replays(lab, "torch", "cuda"), _replays(lab, "jit", "cpu"), atol=1e-4)
    tables = []
    for device in ("cpu", "cuda"):
        out = tmp_path / device
        assert main(["--bags", str(lab["bags"]), "--device", device, "--checkpoint", str(lab["model"]),
                     "--reader-config", str(lab["spec"]), "--out", str(out)]) == 0
        tables.append([{k: v for k, v in row.items() if k != "score"} for row in _table(out)])
    assert tables[0] == tables[1] and tables[0]


@pytest.mark.parametrize("backend", ["jit", "numpy"])
def test_the_compiled_backends_and_the_lstm_refuse_a_gpu_device(backend: str) -> None:
    ompn = build_policy(CONFIG)
    with pytest.raises(StreamingInputError, match="CPU only"):
        build_stepper(ompn, backend, "cuda")  # type: ignore[arg-type]
    lstm = build_policy(OMPNConfig(obs_dim=4, action_type="continuous", action_dim=2, arch="lstm"))
    with pytest.raises(StreamingInputError, match="CPU only"):
        build_stepper(lstm, backend, "cuda")  # type: ignore[arg-type]
