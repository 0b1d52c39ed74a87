"""Behaviour-cloning loss with the 'done' augmentation (paper §3.2; docs/craft.md §3.8, docs/dial.md §4.3).

Discrete (Craft): ``p'(a) = softmax(logits)_a (1 - pi_end)`` for env actions, ``p'(done) = pi_end``.
Continuous (Dial): ``log p' = log(1 - pi_end) + log N(a; mu, var I)`` for real steps and
``log pi_end`` at the appended done step (the episode's final observation row).
Loss = sum over valid steps of ``-log p'`` / number of valid steps (mean per token over the batch).
pi_end is clamped to [1e-9, 1 - 1e-9] as in the code; ``log(1 - pi_end)`` is taken on the clamped
complement so it stays finite in float32.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import LossInputError
from ompn_ros.model.policy import SequenceOutput, gaussian_log_prob

PI_END_CLAMP = 1e-9


def done_log_probs(pi_end: Tensor) -> tuple[Tensor, Tensor]:
    """``(log pi_end, log(1 - pi_end))`` with pi_end clamped to [1e-9, 1 - 1e-9]."""
    return (
        torch.log(pi_end.clamp_min(PI_END_CLAMP)),
        torch.log((1.0 - pi_end).clamp_min(PI_END_CLAMP)),
    )


def step_log_probs(
    out: SequenceOutput,
    actions: Tensor,
    done_mask: Tensor,
    config: OMPNConfig,
    action_scale: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Per-step ``log p'(a_t)`` ``[B, T]`` and the done indicator ``[B, T]`` (see module docstring).

    ``action_scale`` (continuous, ``action_norm='standard'``): the per-dimension std; the Gaussian is
    then taken on the standardised residual ``(a - mu) / std`` (the model's own units)."""
    batch, steps = out.mask.shape
    if done_mask.shape != (batch, steps) or done_mask.dtype != torch.bool:
        raise LossInputError(
            f"done_mask must be a [B, T] = {(batch, steps)} bool tensor, got {tuple(done_mask.shape)} "
            f"{done_mask.dtype}"
        )
    log_end, log_not_end = done_log_probs(out.pi_end)
    if config.action_type == "discrete":
        if actions.shape != (batch, steps) or actions.dtype not in (torch.int64, torch.int32):
            raise LossInputError(
                f"discrete actions must be [B, T] = {(batch, steps)} int64 (value {config.action_dim} = "
                f"done), got {tuple(actions.shape)} {actions.dtype}"
            )
        actions = actions.long()
        valid_actions = actions[out.mask]
        if valid_actions.numel() and (
            int(valid_actions.min()) < 0 or int(valid_actions.max()) > config.action_dim
        ):
            raise LossInputError(
                f"discrete actions must lie in 0..{config.action_dim} ({config.action_dim} = done) "
                "on valid steps"
            )
        is_done = done_mask | (actions == config.action_dim)
        log_softmax = torch.log_softmax(out.action_out, dim=-1)
        env_action = actions.clamp(0, config.action_dim - 1).unsqueeze(-1)
        log_env = log_softmax.gather(-1, env_action).squeeze(-1) + log_not_end
    else:
        if actions.shape != (batch, steps, config.action_dim) or not actions.is_floating_point():
            raise LossInputError(
                f"continuous actions must be float [B, T, A] = {(batch, steps, config.action_dim)}, "
                f"got {tuple(actions.shape)} {actions.dtype}"
            )
        is_done = done_mask
        mean = out.action_out
        if action_scale is not None:
            actions, mean = actions / action_scale, mean / action_scale
        log_env = log_not_end + gaussian_log_prob(actions, mean, config.action_variance)
    return torch.where(is_done, log_end, log_env), is_done


def bc_loss(
    out: SequenceOutput,
    actions: Tensor,
    mask: Tensor,
    done_mask: Tensor,
    config: OMPNConfig,
    *,
    no_done_loss: bool = False,
    action_scale: Tensor | None = None,
) -> tuple[Tensor, dict[str, float]]:
    """Mean ``-log p'(a_t)`` over valid steps, and scalar statistics.

    Args:
        out: model outputs for ``[B, T]`` steps.
        actions: discrete ``[B, T]`` int64 where value ``action_dim`` means done; continuous
            ``[B, T, A]`` float (the value at done steps is ignored).
        mask: ``[B, T]`` bool, valid steps (including the appended done step).
        done_mask: ``[B, T]`` bool, the appended done step of each episode.  Discrete: a step is
            also a done step when its action equals ``action_dim``.
        no_done_loss: the "No Done" ablation: done steps leave the numerator but stay in the
            denominator (docs/craft.md §3.8, ``ignore_index``).
        action_scale: continuous actions with ``action_norm='standard'``: the policy's
            :meth:`~ompn_ros.model.policy.PolicyInputs.action_scale` (residuals are divided by it).

    Returns:
        ``(loss, stats)`` with stats ``loss``, ``nll_action`` (mean over real steps), ``nll_done``
        (mean over done steps), ``pi_end_done``, ``pi_end_real``, ``n_valid`` and, for discrete
        actions, ``accuracy`` (argmax of p' including done, over valid steps).
    """
    if mask.shape != out.mask.shape or mask.dtype != torch.bool:
        raise LossInputError(
            f"mask must be [B, T] bool like the outputs {tuple(out.mask.shape)}, got {tuple(mask.shape)}"
        )
    log_p, is_done = step_log_probs(out, actions, done_mask, config, action_scale)
    nll = -log_p
    counted = mask & ~is_done if no_done_loss else mask
    n_valid = mask.sum()
    loss = torch.where(counted, nll, 0.0).sum() / n_valid.clamp_min(1)

    with torch.no_grad():
        real, done = mask & ~is_done, mask & is_done

        def masked_mean(values: Tensor, where: Tensor) -> float:
            count = int(where.sum())
            return float(torch.where(where, values, 0.0).sum() / count) if count else float("nan")

        stats = {
            "loss": float(loss.detach()),
            "nll_action": masked_mean(nll, real),
            "nll_done": masked_mean(nll, done),
            "pi_end_done": masked_mean(out.pi_end, done),
            "pi_end_real": masked_mean(out.pi_end, real),
            "n_valid": float(n_valid),
        }
        if config.action_type == "discrete":
            probs = torch.softmax(out.action_out, dim=-1) * (1 - out.pi_end).unsqueeze(-1)
            full = torch.cat([probs, out.pi_end.unsqueeze(-1)], dim=-1)
            target = torch.where(is_done, config.action_dim, actions.long())
            stats["accuracy"] = masked_mean((full.argmax(-1) == target).float(), mask)
    return loss, stats
