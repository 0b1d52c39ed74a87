"""Gated recursive cells of the ordered memory (paper appendix A; docs/craft.md §3.3–3.4).

Each memory slot owns one untied :class:`ComCell` (bottom-up, the horizontal update F) and
slots 2..n own one :class:`DecomCell` (top-down, the vertical expansion h).  The :class:`ScoreMLP`
(the score G of the stick-breaking process) is shared by all slots.

Parameter layout (relied upon by the fused training path in ``fused.py`` and the numpy streaming
path in ``streaming.py``, which slice these weights by input block):

* ComCell ``fc1``: Linear(4H -> 4H) on ``[v; h; x; e]``, ``fc2``: Linear(4H -> 4H) -> ``[g (3H); c (H)]``.
* DecomCell ``fc1``: Linear(3H -> 4H) on ``[p; x; e]``, ``fc2``: Linear(4H -> 3H) -> ``[g (2H); c (H)]``.
* ScoreMLP ``fc1``: Linear(4H -> H) on ``[x; e; M^{t-1}_i; C_i]``, ``fc2``: Linear(H -> 1).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

LN_EPS = 1e-5


def plain_layer_norm(x: Tensor) -> Tensor:
    """LayerNorm over the last dim without affine parameters (the cells' output norm)."""
    return F.layer_norm(x, (x.shape[-1],), eps=LN_EPS)


class GatedCell(nn.Module):
    """The layers of a gated cell with ``gates`` gates over ``inputs`` input blocks of size H:
    ``fc1``: Linear(inputs·H -> 4H), ``fc2``: Linear(4H -> (gates + 1)·H) -> ``[g (gates·H); c (H)]``,
    ``gate_norm``: the affine LayerNorm of ``g`` (the layout of the module docstring)."""

    def __init__(self, hidden: int, inputs: int, gates: int) -> None:
        super().__init__()
        self.hidden = hidden
        self.fc1 = nn.Linear(inputs * hidden, 4 * hidden)
        self.fc2 = nn.Linear(4 * hidden, (gates + 1) * hidden)
        self.gate_norm = nn.LayerNorm(gates * hidden, eps=LN_EPS)


class ComCell(GatedCell):
    """Bottom-up cell C_i = F(C_{i-1}, x, M^{t-1}_i) (paper §3.1).

    ``z = W2 ReLU(W1 [v; h; u] + b1) + b2``; ``z = [g (3H), c (H)]``;
    ``[g_v, g_h, g_c] = sigmoid(LN_aff(g))``; output ``LN(g_v*v + g_h*h + g_c*c)``.
    """

    def __init__(self, hidden: int) -> None:
        super().__init__(hidden, inputs=4, gates=3)

    def forward(self, v: Tensor, h: Tensor, u: Tensor) -> Tensor:
        z = self.fc2(F.relu(self.fc1(torch.cat([v, h, u], dim=-1))))
        g, c = z.split([3 * self.hidden, self.hidden], dim=-1)
        g_v, g_h, g_c = torch.sigmoid(self.gate_norm(g)).chunk(3, dim=-1)
        return plain_layer_norm(g_v * v + g_h * h + g_c * c)


class DecomCell(GatedCell):
    """Top-down cell M_hat_{i-1} = h(p, x) with p = rcp_i C_i + (1 - rcp_i) M_hat_i (paper §3.1).

    ``z = W2 ReLU(W1 [p; u] + b1) + b2``; ``z = [g (2H), c (H)]``; ``[g_p, g_c] = sigmoid(LN_aff(g))``;
    output ``LN(g_p*p + g_c*c)``.
    """

    def __init__(self, hidden: int) -> None:
        super().__init__(hidden, inputs=3, gates=2)

    def forward(self, p: Tensor, u: Tensor) -> Tensor:
        z = self.fc2(F.relu(self.fc1(torch.cat([p, u], dim=-1))))
        g, c = z.split([2 * self.hidden, self.hidden], dim=-1)
        g_p, g_c = torch.sigmoid(self.gate_norm(g)).chunk(2, dim=-1)
        return plain_layer_norm(g_p * p + g_c * c)


class ScoreMLP(nn.Module):
    """Score logit s_i with beta_i = sigmoid(s_i) = 1 - f_i, "expand at slot i" (docs/craft.md §3.4).

    Input ``[x; e; M^{t-1}_i; C_i]`` (the code's choice; the paper writes G(x, C_i, M^t_i)).
    """

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(4 * hidden, hidden)
        self.fc2 = nn.Linear(hidden, 1)

    def forward(self, u: Tensor, m_prev: Tensor, c: Tensor) -> Tensor:
        """Return the logit s (``[..., 1]``)."""
        hidden = F.leaky_relu(self.fc1(torch.cat([u, m_prev, c], dim=-1)), negative_slope=0.01)
        return self.fc2(hidden)
