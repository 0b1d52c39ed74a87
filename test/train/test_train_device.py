"""``train.device: auto | cpu | cuda``: every tensor follows the policy, checkpoints load on the CPU."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.cli import train as train_cli
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train import evaluation, synthetic, trainer
from ompn_ros.train.averaging import WeightAverage
from ompn_ros.train.batching import collate
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.device import batch_to, resolve_device, stray_tensors
from ompn_ros.train.errors import DeviceError, TrainConfigError

GPU = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def _config(**kw: object) -> OMPNConfig:
    obs_dim, action_type, action_dim, _ = synthetic.synthetic_spec("discrete")
    return OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=3,
                      slot_size=16, **kw)  # type: ignore[arg-type]


def test_auto_is_the_gpu_when_there_is_one(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu") == resolve_device("cpu")
    with pytest.raises(DeviceError, match=r"train.device=cuda, but torch sees no GPU.*use train.device=cpu"):
        resolve_device("cuda")
    with pytest.raises(DeviceError, match="must be one of"):
        resolve_device("gpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("cuda")
    with pytest.raises(TrainConfigError, match="device"):
        TrainConfig(device="tpu")  # type: ignore[arg-type]


def test_ompn_train_on_cuda_without_a_gpu_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code = train_cli.main(["--synthetic", "discrete", "--episodes", "4", "--out", str(tmp_path / "run"),
                           "--set", "train.device=cuda", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "ompn_train: error: train.device=cuda, but torch sees no GPU" in err
    assert not (tmp_path / "run").exists()


def test_batch_to_moves_every_tensor_of_a_batch() -> None:
    episodes = synthetic.make_dataset("discrete", 3, seed=1)
    batch = collate(episodes, "discrete", 4, use_sketch=True)
    batch = dataclasses.replace(batch, teacher_p_hat=torch.zeros(3, batch.obs.shape[1], 4))
    moved = batch_to(batch, torch.device("meta"))
    for field in dataclasses.fields(moved):
        value = getattr(moved, field.name)
        assert value is None or value.device.type == "meta", field.name
    assert batch.obs.device.type == "cpu"  # the original is untouched


@pytest.mark.parametrize("kw", [{"sketch_mode": "sum", "sketch_vocab": 6}, {"arch": "lstm"}])
def test_the_policy_and_its_average_move_whole(kw: dict) -> None:
    """Parameters, buffers (observation normalisation) and any plain tensor attribute follow ``.to``."""
    episodes = synthetic.make_dataset("discrete", 4, seed=2)
    cfg = TrainConfig(iterations=1, batch_size=2, eval_every=1, progress=False, ema_decay=0.9,
                      device="cpu")
    meta = torch.device("meta")
    models = trainer._models(_config(**kw), cfg, episodes, trainer.DistContext(), meta)
    assert stray_tensors(models.policy, meta) == []
    assert models.average is not None and stray_tensors(models.average.module, meta) == []
    policy = build_policy(_config(**kw))
    policy.stray = torch.zeros(2)  # type: ignore[assignment]  # what .to would leave behind
    assert stray_tensors(policy.to(meta), meta) == ["stray"]


def test_training_sends_every_batch_to_the_policy_device(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[str, torch.device, torch.device]] = []

    def spy(where: str):  # records where each batch goes and where the policy is
        def move(batch, device):  # type: ignore[no-untyped-def]
            seen.append((where, device, batch.obs.device))
            return batch_to(batch, device)
        return move

    monkeypatch.setattr(trainer, "batch_to", spy("train"))
    monkeypatch.setattr(evaluation, "batch_to", spy("eval"))
    cfg = TrainConfig(iterations=2, batch_size=4, eval_every=1, progress=False, device="cpu",
                      val_ratio=0.25)
    trainer.train(synthetic.make_dataset("discrete", 8, seed=3), _config(), cfg)
    assert [w for w, _, _ in seen].count("train") == 2 and "eval" in [w for w, _, _ in seen]
    assert {d for _, d, _ in seen} == {torch.device("cpu")}


Weights = dict[str, torch.Tensor]


def _one_step(policy: torch.nn.Module, device: torch.device) -> tuple[dict[str, float], Weights]:
    episodes = synthetic.make_dataset("discrete", 6, seed=4)
    policy = copy.deepcopy(policy).to(device)
    cfg = TrainConfig(batch_size=6, progress=False, device=device.type)
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    stats = trainer.train_step(policy, optimizer, episodes, policy.config, cfg)  # type: ignore[arg-type]
    return stats, {k: v.detach().cpu() for k, v in policy.state_dict().items()}


@GPU
def test_one_training_step_on_the_gpu_matches_the_cpu(tmp_path: Path) -> None:
    torch.manual_seed(0)
    policy = build_policy(_config())
    cpu_stats, cpu_weights = _one_step(policy, torch.device("cpu"))
    gpu_stats, gpu_weights = _one_step(policy, torch.device("cuda"))
    assert gpu_stats["loss"] == pytest.approx(cpu_stats["loss"], rel=1e-4, abs=1e-5)
    for name, value in cpu_weights.items():
        np.testing.assert_allclose(gpu_weights[name].numpy(), value.numpy(), rtol=1e-4, atol=1e-5)
    trained = trainer.train(synthetic.make_dataset("discrete", 8, seed=5), _config(),
                            TrainConfig(iterations=2, batch_size=4, eval_every=1, progress=False,
                                        device="cuda", out_dir=str(tmp_path / "run")))
    assert trained.policy is not None
    loaded, _ = load_checkpoint(tmp_path / "run" / "best")  # written on the GPU, read on the CPU
    assert {t.device.type for t in loaded.state_dict().values()} == {"cpu"}
    save_checkpoint(tmp_path / "again", loaded)


def test_checkpoints_of_a_run_load_on_the_cpu(tmp_path: Path) -> None:
    cfg = TrainConfig(iterations=2, batch_size=4, eval_every=1, progress=False, device="auto",
                      out_dir=str(tmp_path / "run"), ema_decay=0.5)
    trainer.train(synthetic.make_dataset("discrete", 8, seed=6), _config(), cfg)
    for name in ("best", "last", "train_state/LATEST"):
        assert (tmp_path / "run" / name).exists(), name
    loaded, extra = load_checkpoint(tmp_path / "run" / "best")
    assert {t.device.type for t in loaded.state_dict().values()} == {"cpu"}
    assert extra["train_config"]["device"] == "auto"
    WeightAverage(loaded, 0.5)  # an average of the loaded weights is built on the CPU as well
