"""Distillation (``train.distill_from``): teacher targets ride on the episodes, the loss pulls the
student's p_hat towards the teachers' average, and bad teachers are one clear error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.ensemble import write_ensemble
from ompn_ros.train.batching import TEACHER_P_HAT, collate
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.distill import distill_loss, teacher_p_hats, with_teacher_targets
from ompn_ros.train.errors import BatchError, DistillError, TrainConfigError
from ompn_ros.train.evaluation import teacher_forced_p_hat
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import train, train_val_episodes

torch.set_num_threads(1)


def _model_config(n_slots: int = 2) -> OMPNConfig:
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    return OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=n_slots,
                      slot_size=32)


def _cfg(out: Path, **overrides: object) -> TrainConfig:
    base = {"lr": 3e-3, "batch_size": 32, "iterations": 40, "eval_every": 20, "val_ratio": 0.25,
            "progress": False, "threads": 1, "out_dir": str(out)}
    return TrainConfig(**{**base, **overrides})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def episodes() -> list:
    return make_dataset("discrete", 64, seed=1)


@pytest.fixture(scope="module")
def teachers(tmp_path_factory: pytest.TempPathFactory, episodes: list) -> list[Path]:
    root = tmp_path_factory.mktemp("teachers")
    for seed in (0, 1):
        train(episodes, _model_config(), _cfg(root / f"t{seed}", seed=seed, split_seed=0, iterations=60))
    return [root / "t0" / "best", root / "t1" / "best"]


@pytest.mark.slow  # trains teachers; the KL target is checked fast below
def test_targets_are_the_teachers_average_and_collate_pads_them(episodes: list, teachers: list[Path]) -> None:
    targets = teacher_p_hats([str(t) for t in teachers], episodes[:5], _model_config())
    singles = [teacher_forced_p_hat(load_checkpoint(t)[0], episodes[:5])[0] for t in teachers]
    for i, target in enumerate(targets):
        np.testing.assert_allclose(target, (singles[0][i] + singles[1][i]) / 2, atol=1e-6)
        np.testing.assert_allclose(target.sum(-1), 1.0, atol=1e-5)
    batch = collate(with_teacher_targets(episodes[:5], targets), "discrete", _model_config().action_dim)
    assert batch.teacher_p_hat is not None
    for i, ep in enumerate(episodes[:5]):
        np.testing.assert_allclose(batch.teacher_p_hat[i, : ep.length].numpy(), targets[i])
        assert not batch.teacher_p_hat[i, ep.length :].any()  # done step and padding
    assert TEACHER_P_HAT not in episodes[0].extras  # the input episodes are not modified
    assert collate(episodes[:5], "discrete", _model_config().action_dim).teacher_p_hat is None
    bad = with_teacher_targets(episodes[:1], [targets[1][:1]])
    with pytest.raises(BatchError, match=TEACHER_P_HAT):
        collate(bad, "discrete", _model_config().action_dim)


@pytest.mark.slow  # trains teachers; the KL target is checked fast below
def test_an_ensemble_directory_is_its_members(tmp_path: Path, episodes: list, teachers: list[Path]) -> None:
    write_ensemble(tmp_path / "ens", teachers)
    from_dir = teacher_p_hats([str(tmp_path / "ens")], episodes[:3], _model_config())
    from_list = teacher_p_hats([str(t) for t in teachers], episodes[:3], _model_config())
    for a, b in zip(from_dir, from_list, strict=True):
        np.testing.assert_allclose(a, b)


def test_kl_is_zero_at_the_target_and_pulls_towards_it() -> None:
    target = torch.tensor([[[0.1, 0.6, 0.3], [0.5, 0.25, 0.25]]])
    mask = torch.tensor([[True, False]])
    assert float(distill_loss(target, target, mask)) == pytest.approx(0.0, abs=1e-7)
    logits = torch.zeros(1, 2, 3, requires_grad=True)
    loss = distill_loss(torch.softmax(logits, -1), target, mask)
    loss.backward()
    assert float(loss.detach()) > 0
    assert logits.grad is not None and not logits.grad[0, 1].any()  # masked step: no gradient
    assert float(logits.grad[0, 0, 1]) < 0  # raising the under-predicted entry lowers the loss


@pytest.mark.slow  # trains teachers; the KL target is checked fast below
def test_student_moves_towards_its_teachers(tmp_path: Path, episodes: list, teachers: list[Path]) -> None:
    train_eps, _, _ = train_val_episodes(episodes, _cfg(tmp_path, split_seed=0))
    targets = teacher_p_hats([str(t) for t in teachers], train_eps, _model_config())
    kl = {}
    for weight in (0.0, 5.0):
        out = tmp_path / f"w{weight}"
        extra = {"distill_from": [str(t) for t in teachers], "distill_weight": weight} if weight else {}
        train(episodes, _model_config(), _cfg(out, seed=7, split_seed=0, **extra))
        p_hats, _ = teacher_forced_p_hat(load_checkpoint(out / "last")[0], train_eps)
        kl[weight] = float(np.mean([(t * (np.log(t + 1e-8) - np.log(p + 1e-8))).sum(-1).mean()
                                    for t, p in zip(targets, p_hats, strict=True)]))
    assert kl[5.0] < 0.7 * kl[0.0], kl  # same seed and data: only the distillation term differs


@pytest.mark.slow  # trains teachers; the KL target is checked fast below
def test_bad_teachers_and_settings_are_one_clear_error(tmp_path: Path, episodes: list,
                                                       teachers: list[Path]) -> None:
    with pytest.raises(DistillError, match="n_slots=2"):
        teacher_p_hats([str(teachers[0])], episodes[:2], _model_config(n_slots=3))
    with pytest.raises(DistillError, match="nowhere"):
        teacher_p_hats([str(tmp_path / "nowhere")], episodes[:2], _model_config())
    with pytest.raises(TrainConfigError, match="distill_weight"):
        TrainConfig(distill_from=[str(teachers[0])])
    with pytest.raises(TrainConfigError, match="distill_weight"):
        TrainConfig(distill_weight=1.0)
    with pytest.raises(TrainConfigError, match="distill_from"):
        TrainConfig(distill_from="runs/x", distill_weight=1.0)  # type: ignore[arg-type]
    relative = TrainConfig(distill_from=["runs/x/best"], distill_weight=1.0)
    assert relative.distill_from == [str(Path("runs/x/best").resolve())]  # the checkpoint records where
