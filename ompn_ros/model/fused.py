"""Fast training forward of :class:`OMPNPolicy` over whole episodes (same maths as ``policy.step``).

What makes it fast (numerically equivalent to the eager reference up to float32 rounding):

* **Length sorting / packing**: episodes are sorted by length and step t only runs the b_t
  episodes still alive, so padded steps cost nothing (the authors' code runs them,
  docs/design.md#fast-model-paths).  A step's outputs never depend on later steps, so this is exact.
* **Hoisted input projections**: every layer that reads ``u = [x; e]`` (the n ComCells, n-1
  DecomCells, the score MLP and the action head) gets its x-part from ONE matrix product over all
  valid frames of the batch, and its e-part from one product per episode.  Inside the recurrence
  only the genuinely recurrent inputs remain: v of each ComCell, h = M^{t-1}_i of all ComCells
  (one batched matmul over the slots), p of each DecomCell and ``[M^{t-1}_i; C_i]`` of the score
  MLP (all slots in one matmul).  This also removes the e-columns entirely without a sketch.
* **Stacked memory** ``[n, b, m]``: the memory update is a handful of whole-tensor operations.
* **Action head after the loop**: one matmul over all packed outputs O; the observation
  normalisation is folded into the encoder weights.
* The first step (expand from the top) is its own branch without the bottom-up pass or scores.
* Opt-in ``bf16=True`` (training only): the cell and projection matmuls run under
  ``torch.autocast('cpu', dtype=torch.bfloat16)`` (about 1.4-1.5x faster on CPUs with AVX512-BF16);
  layer norms, gates, the memory, the score logits, stick-breaking and the action head stay float32,
  and weight gradients are accumulated in float32.  Default float32 is the reference-equivalent path.

Gradients agree with the reference to float32 rounding (``test_model_policy.py``).
"""

from __future__ import annotations

from typing import Protocol

import torch
import torch.nn.functional as F
from torch import Tensor

from ompn_ros.model.cells import LN_EPS, ComCell, DecomCell, ScoreMLP, plain_layer_norm
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.expansion import SequenceOutput, expansion_sums, stick_breaking, to_p_hat


class FusedModule(Protocol):
    """What the fused path reads of an :class:`~ompn_ros.model.policy.OMPNPolicy` (its weights)."""

    config: OMPNConfig
    encoder: torch.nn.Linear
    obs_mean: Tensor
    obs_scale: Tensor
    score: ScoreMLP
    head: torch.nn.Linear

    @property
    def com_list(self) -> list[ComCell]: ...

    @property
    def decom_list(self) -> list[DecomCell]: ...

    def embed_sketch(self, sketch: Tensor | None, batch_size: int) -> Tensor: ...

    def denormalize_action(self, head_out: Tensor) -> Tensor: ...


def _gated(z: Tensor, split: int, hidden: int, norm: torch.nn.LayerNorm) -> tuple[list[Tensor], Tensor]:
    gates = torch.sigmoid(F.layer_norm(z[:, :split], (split,), norm.weight, norm.bias, LN_EPS))
    return list(gates.split(hidden, dim=1)), z[:, split:]


def _linear_fp32(x: Tensor, weight: Tensor, bias: Tensor | None) -> Tensor:
    """``F.linear`` in float32 even inside a bfloat16 autocast region (score logits, action head)."""
    with torch.autocast("cpu", enabled=False):
        return F.linear(x.float(), weight, bias)


def fused_forward_sequence(
    policy: FusedModule,
    obs: Tensor,
    mask: Tensor,
    lengths: Tensor,
    sketch: Tensor | None,
    bptt: int,
    bf16: bool = False,
) -> SequenceOutput:
    """See :meth:`OMPNPolicy.forward_sequence`; ``lengths`` come from the validated ``mask``."""
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        return _fused(policy, obs, mask, lengths, sketch, bptt)


def _fused(
    policy: FusedModule, obs: Tensor, mask: Tensor, lengths: Tensor, sketch: Tensor | None, bptt: int
) -> SequenceOutput:
    cfg = policy.config
    n, h, a = cfg.n_slots, cfg.slot_size, cfg.action_dim
    batch, steps, _ = obs.shape
    device = obs.device
    lengths = lengths.to("cpu")
    order = torch.argsort(lengths, descending=True, stable=True)
    sorted_len = lengths[order].tolist()
    t_max = sorted_len[0] if batch else 0
    zeros = obs.new_zeros
    if t_max == 0:
        return SequenceOutput(
            zeros(batch, steps, a), zeros(batch, steps, n + 1), zeros(batch, steps, n), mask
        )
    counts = [sum(1 for length in sorted_len if length > t) for t in range(t_max)]
    rank = torch.cat([torch.arange(count) for count in counts])  # position in the sorted batch, time-major
    time = torch.cat([torch.full((count,), t, dtype=torch.long) for t, count in enumerate(counts)])
    orig = order[rank]
    order_d, orig_d, time_d, rank_d = order.to(device), orig.to(device), time.to(device), rank.to(device)

    # x = W_in((s - mean) / scale) + b_in with the normalisation folded into the weights (one pass
    # over the large observation tensor instead of three)
    w_in = policy.encoder.weight / policy.obs_scale
    x_all = F.linear(obs[orig_d, time_d], w_in, policy.encoder.bias - w_in @ policy.obs_mean)  # [N, H]

    # --- hoisted projections of x (all frames) and e (all episodes) -----------------------------------
    com, dec, score, head = policy.com_list, policy.decom_list, policy.score, policy.head
    x_cols = [c.fc1.weight[:, 2 * h : 3 * h] for c in com] + [d.fc1.weight[:, h : 2 * h] for d in dec]
    x_cols.append(score.fc1.weight[:, :h])
    biases: list[Tensor] = [c.fc1.bias for c in com]
    biases += [d.fc1.bias for d in dec] + [score.fc1.bias]
    sizes = [n * 4 * h] + [4 * h] * (n - 1) + [h]  # all ComCells, each DecomCell, the score MLP
    x_proj = torch.addmm(torch.cat(biases), x_all, torch.cat(x_cols).t())  # [N, R]
    head_e: Tensor | None = None
    if cfg.sketch_mode != "none":
        e = policy.embed_sketch(sketch, batch)[order_d]
        e_cols = [c.fc1.weight[:, 3 * h :] for c in com] + [d.fc1.weight[:, 2 * h :] for d in dec]
        e_cols.append(score.fc1.weight[:, h : 2 * h])
        x_proj = x_proj + (e @ torch.cat(e_cols).t())[rank_d]
        head_e = _linear_fp32(e, head.weight[:, h : 2 * h], None)[rank_d]
        m0_top = plain_layer_norm(e)
    else:
        policy.embed_sketch(sketch, batch)  # validates: no sketch allowed
        m0_top = zeros(batch, h)
    # per-step row blocks first (one SplitBackward for the whole tensor), then the column blocks
    step_parts = [chunk.split(sizes, dim=1) for chunk in x_proj.split(counts, dim=0)]
    x_steps = x_all.split(counts, dim=0)

    com_v = [c.fc1.weight[:, :h].t() for c in com]  # [H, 4H] on v = C_{i-1}
    com_h = torch.stack([c.fc1.weight[:, h : 2 * h].t() for c in com])  # [n, H, 4H] on h = M^{t-1}_i
    dec_rec = [d.fc1.weight[:, :h].t() for d in dec]
    score_rec = score.fc1.weight[:, 2 * h :].t()  # rows [m; c]

    def top_down(cand: Tensor, rcp: Tensor | None, t: int, b: int) -> Tensor:
        """M_hat_{i-1} = DecomCell_i(rcp_i C_i + (1 - rcp_i) M_hat_i, u); rcp None = first step."""
        m_hat: list[Tensor] = [cand.new_zeros(b, h) for _ in range(n)]
        if not cfg.no_top_down:
            for i in range(n - 1, 0, -1):
                if rcp is None:  # first step: rcp = 1 at the top, 0 below
                    parent = cand[i] if i == n - 1 else m_hat[i]
                else:
                    r = rcp[:, i : i + 1]
                    parent = r * cand[i] + (1 - r) * m_hat[i]
                k = i - 1
                hidden = F.relu(torch.addmm(step_parts[t][1 + k], parent, dec_rec[k]))
                z = F.linear(hidden, dec[k].fc2.weight, dec[k].fc2.bias)
                (g_p, g_c), c = _gated(z, 2 * h, h, dec[k].gate_norm)
                m_hat[k] = plain_layer_norm(g_p * parent + g_c * c)
        return torch.stack(m_hat)

    out_o, out_p_hat, out_pi = [], [], []
    memory = zeros(n, batch, h)  # [n, b, H], slot 1 first
    for t in range(t_max):
        b = counts[t]
        if t == 0:
            m_prev = torch.cat([zeros(n - 1, b, h), m0_top[:b].unsqueeze(0)])
            m_hat = top_down(m_prev, None, t, b)
            memory = torch.cat([m_hat[: n - 1], m_prev[n - 1 :]])
            pi_hat = zeros(b, n)
            pi_hat[:, -1] = 1.0
            pi_end = zeros(b)
            pi = pi_hat
        else:
            m_prev = memory[:, :b]
            if cfg.no_bottom_up:
                cand = m_prev
            else:
                com_in = step_parts[t][0].view(b, n, 4 * h).transpose(0, 1)
                rec_h = torch.baddbmm(com_in, m_prev, com_h)  # h-parts of all slots at once
                cand_list, below = [], x_steps[t]
                for i in range(n):
                    if cfg.no_bottom_up_recurrence:  # v = 0
                        hidden = F.relu(rec_h[i])
                    else:
                        hidden = F.relu(torch.addmm(rec_h[i], below, com_v[i]))
                    z = F.linear(hidden, com[i].fc2.weight, com[i].fc2.bias)
                    (g_v, g_h, g_c), c = _gated(z, 3 * h, h, com[i].gate_norm)
                    mixed = g_h * m_prev[i] + g_c * c
                    if not cfg.no_bottom_up_recurrence:
                        mixed = mixed + g_v * below
                    below = plain_layer_norm(mixed)
                    cand_list.append(below)
                cand = torch.stack(cand_list)
            score_in = torch.cat([m_prev, cand], dim=2)  # [n, b, 2H]
            hidden = F.leaky_relu(torch.matmul(score_in, score_rec) + step_parts[t][n], 0.01)
            logits = _linear_fp32(hidden, score.fc2.weight, score.fc2.bias).squeeze(-1).t()  # [b, n]
            pi_hat, pi_end = stick_breaking(logits)
            pi, rcp, cp = expansion_sums(pi_hat)
            m_hat = top_down(cand, rcp, t, b)
            r = rcp.t().unsqueeze(-1)  # [n, b, 1]
            if cfg.memory_update == "paper":
                memory = m_prev * (1 - cp.t().unsqueeze(-1)) + cand * pi.t().unsqueeze(-1) + m_hat * (1 - r)
            else:
                memory = r * cand + (1 - r) * m_hat
        out_o.append(memory[0])
        out_p_hat.append(to_p_hat(pi_hat, pi_end))
        out_pi.append(pi)
        if (t + 1) % bptt == 0:
            memory = memory.detach()

    head_w = torch.cat([head.weight[:, :h], head.weight[:, 2 * h :]], dim=1)  # on [O; x]
    action = _linear_fp32(torch.cat([torch.cat(out_o), x_all.float()], dim=1), head_w, head.bias)
    if head_e is not None:
        action = action + head_e
    action = policy.denormalize_action(action)
    flat = (orig_d * steps + time_d).to(device)

    def unpack(packed: Tensor) -> Tensor:
        full = packed.new_zeros(batch * steps, packed.shape[1]).index_copy(0, flat, packed)
        return full.view(batch, steps, packed.shape[1])

    return SequenceOutput(
        action_out=unpack(action), p_hat=unpack(torch.cat(out_p_hat)), pi=unpack(torch.cat(out_pi)), mask=mask
    )
