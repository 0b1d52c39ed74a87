"""bc_loss checked by hand on tiny cases."""

from __future__ import annotations

import math

import pytest
import torch

from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import LossInputError
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.policy import OMPNPolicy, SequenceOutput


def p_hat_with_end(pi_end: list[list[float]]) -> torch.Tensor:
    """p_hat [B, T, 3] (n=2) whose pi_end is given and whose slots split the rest equally."""
    end = torch.tensor(pi_end)
    return torch.stack([end, (1 - end) / 2, (1 - end) / 2], dim=-1)


def discrete_case() -> tuple[SequenceOutput, torch.Tensor, torch.Tensor, torch.Tensor, OMPNConfig]:
    cfg = OMPNConfig(obs_dim=3, action_type="discrete", action_dim=2, n_slots=2, slot_size=4)
    logits = torch.tensor(
        [[[0.0, 0.0], [math.log(3.0), 0.0], [5.0, -1.0]], [[0.0, 0.0], [9.0, 9.0], [9.0, 9.0]]]
    )
    mask = torch.tensor([[True, True, True], [True, False, False]])
    p_hat = p_hat_with_end([[0.0, 0.2, 0.5], [0.0, 0.7, 0.7]])
    out = SequenceOutput(action_out=logits, p_hat=p_hat, pi=p_hat[..., 1:], mask=mask)
    actions = torch.tensor([[0, 1, 2], [1, 0, 0]])
    done = torch.tensor([[False, False, True], [False, False, False]])
    return out, actions, mask, done, cfg


def test_discrete_loss_by_hand() -> None:
    out, actions, mask, done, cfg = discrete_case()
    loss, stats = bc_loss(out, actions, mask, done, cfg)
    # row 0: ln 2 (pi_end 0 -> clamped 1e-9), -ln(0.25 * 0.8), -ln 0.5 at done; row 1: ln 2; 4 valid steps
    expected = (math.log(2) + math.log(5) + math.log(2) + math.log(2)) / 4
    assert loss.item() == pytest.approx(expected, abs=1e-6)
    assert stats["n_valid"] == 4
    assert stats["nll_done"] == pytest.approx(math.log(2), abs=1e-6)
    assert stats["pi_end_done"] == pytest.approx(0.5)
    # argmax of p': t0 tie -> class 0 (right), t1 0.6 vs 0.2 (wrong), t2 done 0.5 vs ~0.5*0.9975 (right),
    # row 1: tie -> 0, target 1 (wrong)
    assert stats["accuracy"] == pytest.approx(0.5)


def test_no_done_loss_keeps_the_denominator() -> None:
    out, actions, mask, done, cfg = discrete_case()
    loss, _ = bc_loss(out, actions, mask, done, cfg, no_done_loss=True)
    assert loss.item() == pytest.approx((math.log(2) + math.log(5) + math.log(2)) / 4, abs=1e-6)


def test_continuous_loss_by_hand() -> None:
    cfg = OMPNConfig(obs_dim=3, action_type="continuous", action_dim=2, n_slots=2, slot_size=4)
    mean = torch.tensor([[[0.0, 0.0], [7.0, 7.0], [0.0, 0.0]]])
    mask = torch.tensor([[True, True, False]])
    done = torch.tensor([[False, True, False]])
    out = SequenceOutput(
        action_out=mean, p_hat=p_hat_with_end([[0.1, 0.3, 0.9]]), pi=torch.zeros(1, 3, 2), mask=mask
    )
    actions = torch.tensor([[[1.0, 0.0], [123.0, 4.0], [0.0, 0.0]]])
    loss, stats = bc_loss(out, actions, mask, done, cfg)
    real = -(math.log(0.9) - 1 / 1.2 - math.log(2 * math.pi * 0.6))
    assert loss.item() == pytest.approx((real - math.log(0.3)) / 2, abs=1e-5)
    assert stats["nll_action"] == pytest.approx(real, abs=1e-5)
    assert "accuracy" not in stats


def test_loss_is_finite_and_differentiable_on_a_real_model() -> None:
    torch.manual_seed(0)
    cfg = OMPNConfig(obs_dim=6, action_type="discrete", action_dim=5, n_slots=3, slot_size=8)
    policy = OMPNPolicy(cfg)
    obs = torch.randn(2, 4, 6)
    mask = torch.tensor([[1, 1, 1, 1], [1, 1, 0, 0]], dtype=torch.bool)
    done = torch.tensor([[0, 0, 0, 1], [0, 1, 0, 0]], dtype=torch.bool)
    actions = torch.tensor([[0, 4, 3, 5], [2, 5, 0, 0]])
    loss, _ = bc_loss(policy.forward_sequence(obs, mask), actions, mask, done, cfg)
    loss.backward()
    assert torch.isfinite(loss) and policy.encoder.weight.grad is not None
    assert policy.encoder.weight.grad.abs().sum() > 0


def test_bad_targets_raise() -> None:
    out, actions, mask, done, cfg = discrete_case()
    with pytest.raises(LossInputError, match=r"must lie in 0\.\.2"):
        bc_loss(out, torch.where(mask, 3, 0), mask, done, cfg)
    with pytest.raises(LossInputError, match="discrete actions must be"):
        bc_loss(out, actions.float(), mask, done, cfg)
    with pytest.raises(LossInputError, match="done_mask must be"):
        bc_loss(out, actions, mask, done[:, :2], cfg)
