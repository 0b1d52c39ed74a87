"""The expansion distribution of the ordered memory (Lu et al., ICLR 2021, §3.1) and sequence outputs.

Shared by the eager reference (``policy.py``) and the fused training path (``fused.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class SequenceOutput:
    """Outputs of :meth:`OMPNPolicy.forward_sequence`; padded steps hold zeros.

    ``action_out [B, T, A]``, ``p_hat [B, T, n+1]`` ([pi_end, top, ..., bottom]), ``pi [B, T, n]``
    (lowest slot first), ``mask [B, T]`` (valid steps).
    """

    action_out: Tensor
    p_hat: Tensor
    pi: Tensor
    mask: Tensor

    @property
    def pi_end(self) -> Tensor:
        return self.p_hat[..., 0]


def stick_breaking(logits: Tensor) -> tuple[Tensor, Tensor]:
    """Slot probabilities and pi_end from score logits ``[..., n]`` (lowest slot first).

    ``beta_i = sigmoid(s_i)``; ``pi_hat_i = beta_i prod_{j<i}(1 - beta_j)``; ``pi_end = prod_j (1 - beta_j)``
    (paper §3.1 with f_i = 1 - beta_i).  Returns ``(pi_hat [..., n], pi_end [...])``.
    """
    beta = torch.sigmoid(logits)
    survive = torch.cumprod(torch.sigmoid(-logits), dim=-1)  # prod_{j<=i} f_j
    below = torch.cat([torch.ones_like(survive[..., :1]), survive[..., :-1]], dim=-1)
    return beta * below, survive[..., -1]


def expansion_sums(pi_hat: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Normalise pi_hat (L1, floor 1e-12) and return ``(pi, rcp, cp)``, all ``[..., n]`` lowest first."""
    pi = pi_hat / pi_hat.sum(dim=-1, keepdim=True).clamp_min(1e-12)
    rcp = torch.cumsum(pi, dim=-1)
    cp = torch.flip(torch.cumsum(torch.flip(pi, dims=[-1]), dim=-1), dims=[-1])
    return pi, rcp, cp


def to_p_hat(pi_hat: Tensor, pi_end: Tensor) -> Tensor:
    """``[pi_end, slot n, ..., slot 1]`` from ``pi_hat`` (lowest first) and ``pi_end``."""
    return torch.cat([pi_end.unsqueeze(-1), torch.flip(pi_hat, dims=[-1])], dim=-1)


__all__ = ["SequenceOutput", "expansion_sums", "stick_breaking", "to_p_hat"]
