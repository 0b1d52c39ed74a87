"""Action normalisation (``train.action_norm`` / ``OMPNConfig.action_norm``): the head fits standardised
actions, the loss is taken on the standardised residual, every inference path outputs the data's units,
and checkpoints written before the option still load as ``'none'``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ConfigError, ModelInputError
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.policy import OMPNPolicy, gaussian_log_prob
from ompn_ros.model.streaming import StreamingPolicy
from ompn_ros.train.batching import action_normalization, collate
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import train, train_val_episodes

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[2]
MEAN = np.array([3.0, -2.0, 0.5], np.float32)
STD = np.array([7.0, 0.25, 2.0], np.float32)


def _config(arch: str = "ompn", **overrides: object) -> OMPNConfig:
    fields = {"obs_dim": 5, "action_type": "continuous", "action_dim": 3, "n_slots": 2, "slot_size": 8,
              "action_norm": "standard", "arch": arch, **overrides}
    return OMPNConfig(**fields)  # type: ignore[arg-type]


def _policy(arch: str = "ompn") -> torch.nn.Module:
    torch.manual_seed(0)
    policy = build_policy(_config(arch))
    policy.set_action_normalization(MEAN, STD)
    return policy


def test_config_validates_action_norm_and_reads_old_configs_as_none() -> None:
    with pytest.raises(ConfigError, match="action_norm"):
        _config(action_norm="minmax")
    with pytest.raises(ConfigError, match="continuous"):
        OMPNConfig(obs_dim=5, action_type="discrete", action_dim=3, action_norm="standard")
    old = {"obs_dim": 5, "action_type": "continuous", "action_dim": 3}
    assert OMPNConfig.from_dict(old).action_norm == "none"
    assert "action_std" not in build_policy(OMPNConfig.from_dict(old)).state_dict()


@pytest.mark.parametrize("arch", ["ompn", "lstm"])
def test_outputs_are_the_head_in_the_data_units(arch: str) -> None:
    policy = _policy(arch)
    obs, mask = torch.randn(2, 6, 5), torch.ones(2, 6, dtype=torch.bool)
    with torch.no_grad():
        normed = policy.forward_sequence(obs, mask).action_out
        policy.action_std.fill_(1.0)
        policy.action_mean.zero_()
        raw = policy.forward_sequence(obs, mask).action_out
    assert torch.allclose(normed, raw * torch.from_numpy(STD) + torch.from_numpy(MEAN), atol=1e-5)


def test_fused_reference_and_streaming_paths_agree() -> None:
    policy = _policy()
    assert isinstance(policy, OMPNPolicy)
    obs, mask = torch.randn(1, 8, 5), torch.ones(1, 8, dtype=torch.bool)
    with torch.no_grad():
        fused = policy.forward_sequence(obs, mask).action_out[0].numpy()
        reference = policy.forward_sequence(obs, mask, impl="reference").action_out[0].numpy()
    assert np.allclose(fused, reference, atol=1e-4)
    for backend in ("numpy", "torch"):
        stepper = StreamingPolicy(policy, backend=backend)  # type: ignore[arg-type]
        live = np.stack([stepper.step(obs[0, t].numpy()).action for t in range(8)])
        assert np.allclose(live, fused, atol=1e-4), backend


def test_loss_is_the_gaussian_of_the_standardised_residual() -> None:
    episodes = make_dataset("continuous", 2, seed=3)
    config = _config(obs_dim=episodes[0].observations.shape[1], action_dim=episodes[0].actions.shape[1])
    policy = build_policy(config)
    std = np.linspace(0.5, 4.0, config.action_dim).astype(np.float32)
    policy.set_action_normalization(np.zeros(config.action_dim, np.float32), std)
    batch = collate(episodes, "continuous", config.action_dim, False)
    out = policy.forward_sequence(batch.obs, batch.mask)
    _, scaled = bc_loss(out, batch.actions, batch.mask, batch.done_mask, config,
                        action_scale=policy.action_scale())
    _, plain = bc_loss(out, batch.actions, batch.mask, batch.done_mask, config)
    real = batch.mask & ~batch.done_mask
    s = torch.from_numpy(std)
    expected = -gaussian_log_prob(batch.actions / s, out.action_out / s, config.action_variance)[real]
    log_not_end = torch.log((1 - out.pi_end[real]).clamp_min(1e-9))
    assert scaled["nll_action"] == pytest.approx(float((expected - log_not_end).mean().detach()), rel=1e-5)
    assert scaled["nll_action"] != pytest.approx(plain["nll_action"], rel=1e-3)


def test_statistics_and_bad_values() -> None:
    episodes = make_dataset("continuous", 4, seed=1)
    mean, std = action_normalization(episodes)
    stacked = np.concatenate([e.actions for e in episodes])
    assert np.allclose(mean, stacked.mean(0), atol=1e-5) and np.allclose(std, stacked.std(0), atol=1e-5)
    policy = _policy()
    with pytest.raises(ModelInputError, match="std"):
        policy.set_action_normalization(MEAN, np.zeros(3))
    with pytest.raises(ModelInputError, match="size"):
        policy.set_action_normalization(MEAN[:2], STD[:2])


def test_trainer_stores_the_training_split_statistics(tmp_path: Path) -> None:
    episodes = make_dataset("continuous", 12, seed=0)
    obs_dim, action_type, action_dim, _ = synthetic_spec("continuous")
    config = OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim,  # type: ignore[arg-type]
                        n_slots=2, slot_size=8)
    cfg = TrainConfig(iterations=2, eval_every=2, batch_size=4, val_ratio=0.25, progress=False,
                      action_norm="standard", out_dir=str(tmp_path / "run"))
    result = train(episodes, config, cfg)
    assert result.policy.config.action_norm == "standard"
    saved = json.loads((tmp_path / "run" / "best" / "config.json").read_text())
    assert saved["action_norm"] == "standard"
    loaded, _ = load_checkpoint(tmp_path / "run" / "best")
    train_eps, val_eps, _ = train_val_episodes(episodes, cfg)
    assert train_eps and val_eps
    mean, std = action_normalization(train_eps)  # the training split's, not all episodes'
    assert np.allclose(loaded.action_mean.numpy(), mean) and np.allclose(loaded.action_std.numpy(), std)
    assert not np.allclose(mean, action_normalization(episodes)[0])
    discrete = OMPNConfig(obs_dim=4, action_type="discrete", action_dim=3)
    with pytest.raises(TrainConfigError, match="action_norm"):
        train(make_dataset("discrete", 4), discrete, TrainConfig(iterations=1, progress=False,
                                                                  action_norm="standard"))
    with pytest.raises(TrainConfigError, match="action_norm"):
        TrainConfig(action_norm="robust")  # type: ignore[arg-type]


def test_round_trip_and_shipped_checkpoints_stay_unnormalised(tmp_path: Path) -> None:
    policy = _policy()
    save_checkpoint(tmp_path / "ck", policy)
    loaded, _ = load_checkpoint(tmp_path / "ck")
    assert np.allclose(loaded.action_std.numpy(), STD) and np.allclose(loaded.action_mean.numpy(), MEAN)
    for domain in ("dial", "craft"):
        shipped, _ = load_checkpoint(ROOT / "ompn_ros" / "checkpoints" / domain)
        assert shipped.config.action_norm == "none"
        assert not any(k.startswith("action_") for k in shipped.state_dict())
