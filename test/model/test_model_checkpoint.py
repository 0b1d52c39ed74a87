"""Checkpoint round trip and error reporting."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.atomic import remove_stale_temps
from ompn_ros.checkpoints import MissingCheckpointError, shipped_checkpoint
from ompn_ros.model import checkpoint
from ompn_ros.model.build import build_policy, check_model_size, expected_tensors
from ompn_ros.model.checkpoint import load_checkpoint, load_config, save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import CheckpointError
from ompn_ros.model.load import shipped_stepper
from ompn_ros.model.lstm import LSTMPolicy
from ompn_ros.model.policy import OMPNPolicy


def policy() -> OMPNPolicy:
    torch.manual_seed(3)
    cfg = OMPNConfig(
        obs_dim=7,
        action_type="continuous",
        action_dim=3,
        n_slots=2,
        slot_size=8,
        sketch_mode="sum",
        sketch_vocab=5,
        memory_update="code",
    )
    p = OMPNPolicy(cfg)
    p.set_obs_normalization(np.arange(7, dtype=np.float32), np.full(7, 2.5, dtype=np.float32))
    return p


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    original = policy()
    save_checkpoint(tmp_path / "ckpt", original, extra={"lr": 1e-3, "metrics": {"f1": 0.9}})
    loaded, extra = load_checkpoint(tmp_path / "ckpt")
    assert loaded.config == original.config
    assert extra == {"lr": 1e-3, "metrics": {"f1": 0.9}}
    reference = original.state_dict()
    assert set(loaded.state_dict()) == set(reference)
    for name, value in loaded.state_dict().items():
        assert torch.equal(value, reference[name]), name
    assert not loaded.training
    # overwriting an existing checkpoint works and leaves no temporary directories behind
    save_checkpoint(tmp_path / "ckpt", loaded)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt"]
    assert load_checkpoint(tmp_path / "ckpt")[1] == {}


def test_corrupt_weights_name_the_file(tmp_path: Path) -> None:
    save_checkpoint(tmp_path / "c", policy())
    (tmp_path / "c" / "model.safetensors").write_bytes(b"\x00garbage" * 10)
    with pytest.raises(CheckpointError, match=r"c/model\.safetensors: not a readable safetensors file"):
        load_checkpoint(tmp_path / "c")


def test_config_weight_mismatch_names_the_tensor(tmp_path: Path) -> None:
    save_checkpoint(tmp_path / "c", policy())
    cfg_file = tmp_path / "c" / "config.json"
    cfg = json.loads(cfg_file.read_text())
    cfg["slot_size"] = 16
    cfg_file.write_text(json.dumps(cfg))
    with pytest.raises(
        CheckpointError, match=r"model\.safetensors: tensor 'encoder\.weight' has shape \(8, 7\)"
    ):
        load_checkpoint(tmp_path / "c")
    cfg["slot_size"], cfg["sketch_mode"], cfg["sketch_vocab"] = 8, "none", 0
    cfg_file.write_text(json.dumps(cfg))
    with pytest.raises(CheckpointError, match=r"unexpected \['sketch_embedding\.weight'\]"):
        load_checkpoint(tmp_path / "c")


def test_missing_files_and_versions(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope")
    save_checkpoint(tmp_path / "c", policy())
    cfg_file = tmp_path / "c" / "config.json"
    cfg = json.loads(cfg_file.read_text())
    cfg_file.write_text(json.dumps({**cfg, "version": 7}))
    with pytest.raises(CheckpointError, match=r"config\.json: .*version 7 is not supported"):
        load_checkpoint(tmp_path / "c")
    cfg_file.write_text(json.dumps(cfg))
    meta = tmp_path / "c" / "meta.json"
    meta.write_text(json.dumps({"format_version": 2, "extra": {}}))
    with pytest.raises(CheckpointError, match=r"meta\.json: checkpoint format_version 2"):
        load_checkpoint(tmp_path / "c")
    meta.unlink()
    (tmp_path / "c" / "model.safetensors").unlink()
    with pytest.raises(CheckpointError, match=r"model\.safetensors: missing"):
        load_checkpoint(tmp_path / "c")
    cfg_file.unlink()
    with pytest.raises(CheckpointError, match=r"config\.json: missing"):
        load_checkpoint(tmp_path / "c")


def test_extra_must_be_json(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="not JSON-serializable"):
        save_checkpoint(tmp_path / "c", policy(), extra={"bad": object()})
    assert not (tmp_path / "c").exists()


def test_half_precision_storage_halves_the_file_and_loads_as_float32(tmp_path) -> None:
    policy = OMPNPolicy(OMPNConfig(obs_dim=20, action_type="discrete", action_dim=5, n_slots=2, slot_size=32))
    save_checkpoint(tmp_path / "full", policy)
    save_checkpoint(tmp_path / "half", policy, weights_dtype="float16")
    full = (tmp_path / "full" / "model.safetensors").stat().st_size
    half = (tmp_path / "half" / "model.safetensors").stat().st_size
    assert half < 0.55 * full
    loaded, _ = load_checkpoint(tmp_path / "half")
    for name, value in loaded.state_dict().items():
        original = policy.state_dict()[name]
        assert value.dtype == original.dtype
        if value.is_floating_point():
            torch.testing.assert_close(value, original.half().float(), atol=0, rtol=0)
    # a float16 file that does not say so in meta.json is rejected, not silently cast
    (tmp_path / "half" / "meta.json").write_text('{"format_version": 1, "extra": {}}')
    with pytest.raises(CheckpointError, match="float16"):
        load_checkpoint(tmp_path / "half")


def test_huge_config_is_rejected_before_any_allocation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    save_checkpoint(tmp_path / "ckpt", policy())
    config = json.loads((tmp_path / "ckpt" / "config.json").read_text())

    def no_build(config: OMPNConfig) -> None:
        raise AssertionError("the model was built before the shape check")

    monkeypatch.setattr(checkpoint, "build_policy", no_build)
    config["slot_size"] = 100_000  # 2.6e11 values: would need ~1 TB
    (tmp_path / "ckpt" / "config.json").write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match=r"config\.json.*limit"):
        load_checkpoint(tmp_path / "ckpt")
    config["slot_size"] = 64  # plausible size, but not what the file holds
    (tmp_path / "ckpt" / "config.json").write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match=r"model.safetensors: tensor '.*' has shape \(8,"):
        load_checkpoint(tmp_path / "ckpt")


def test_expected_tensors_match_the_built_model() -> None:
    for arch in ("ompn", "lstm"):
        cfg = OMPNConfig(obs_dim=9, action_type="discrete", action_dim=4, n_slots=2, slot_size=6,
                         sketch_mode="sum", sketch_vocab=3, arch=arch)
        built = {k: (tuple(v.shape), v.dtype) for k, v in build_policy(cfg).state_dict().items()}
        assert expected_tensors(cfg) == built
        assert check_model_size(cfg) == sum(int(np.prod(shape)) for shape, _ in built.values())


def test_save_removes_temporaries_of_killed_writers_only(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f".ckpt.tmp-{dead_pid}-abc123"
    live = tmp_path / f".ckpt.tmp-{os.getppid()}-def456"  # a running process (pytest's parent)
    other = tmp_path / f".other.tmp-{dead_pid}-abc123"  # another checkpoint's: left alone
    for d in (stale, live, other):
        d.mkdir()
    save_checkpoint(tmp_path / "ckpt", policy())
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted(["ckpt", live.name, other.name])
    assert remove_stale_temps(tmp_path) == [other]


def test_build_policy_draws_the_same_initial_weights_as_the_constructors() -> None:
    # the size check builds on the meta device first: it must not consume the random stream
    for arch, cls in (("ompn", OMPNPolicy), ("lstm", LSTMPolicy)):
        cfg = OMPNConfig(obs_dim=9, action_type="discrete", action_dim=4, n_slots=2, slot_size=6, arch=arch)
        torch.manual_seed(5)
        built = build_policy(cfg).state_dict()
        torch.manual_seed(5)
        direct = cls(cfg).state_dict()
        assert all(torch.equal(built[k], direct[k]) for k in direct)


def test_shipped_steppers_load_by_domain() -> None:
    for domain in ("craft", "dial"):
        stepper = shipped_stepper(domain, backend="numpy")
        assert stepper.config == load_config(shipped_checkpoint(domain))
    with pytest.raises(MissingCheckpointError, match="grid"):
        shipped_stepper("grid")
