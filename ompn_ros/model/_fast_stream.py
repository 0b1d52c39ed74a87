"""Low-overhead numpy kernel of one batch-1 OMPN step (the ``'numpy'`` backend of ``streaming.py``).

Same maths as :meth:`OMPNPolicy.step` (paper §3.1, appendix A), arranged for a matrix-vector bound
step where numpy's per-call overhead (~0.5 us) is the other half of the cost:

* **Hoisted input projections**: the x-columns of every ComCell/DecomCell first layer, the score MLP
  and the action head are stacked into one matrix, so x is multiplied once per step; the task
  embedding's contribution (e is constant per episode) is added as one vector computed in
  :meth:`NumpyStepper.reset` (without a sketch e = 0 and those columns are never read).
* **Sparse observations** (Craft's one-hot features, ~60 non-zeros of 1075): the encoder gathers
  the non-zero columns instead of reading the whole ``[m, D]`` matrix (same sum, another order).
* **Gates without a separate sigmoid**: ``sigmoid(y) = (1 + tanh(y / 2)) / 2`` with gamma/2 and beta/2
  folded into the gate LayerNorm, and the common factor 1/2 of the gated sum dropped because the
  following LayerNorm is scale invariant (its eps is multiplied by 4 to stay identical).
* **Preallocated buffers in the order the cells read them**: the second layer's rows are permuted
  to ``[c; g]`` so that ``[v; h; c]`` (ComCell) and ``[p; c]`` (DecomCell) are contiguous and each
  gated sum is one multiply and one reshape-sum; all matrix products write with ``out=``.

Agreement with the torch reference is float32 rounding (tests hold it to 1e-5).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from ompn_ros.model.cells import LN_EPS, ComCell, DecomCell
from ompn_ros.model.policy import OMPNPolicy

SPARSE_FRACTION = 0.25
"""Use the gather encoder when at most this fraction of the observation is non-zero."""


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


class _CellViews:
    """One cell's scratch buffer ``[in_1; ...; in_k; g_1 ... g_k]`` (in_k = c) and its views."""

    def __init__(self, h: int, k: int) -> None:
        self.buf = np.zeros(2 * k * h, np.float32)
        self.first = self.buf[:h]  # v (ComCell) or p (DecomCell)
        self.second = self.buf[h : 2 * h]  # h = M^{t-1}_i (ComCell only)
        self.rec = self.buf[: (k - 1) * h]  # the recurrent first-layer input: [v; h] or [p]
        self.z = self.buf[(k - 1) * h :]  # second-layer output, rows permuted to [c; g]
        self.inputs = self.buf[: k * h]
        self.gates = self.buf[k * h :]
        self.gate_rows = list(self.gates.reshape(k, h))
        self.ones = np.ones(k * h, np.float32)
        self.inv_gates = 1.0 / (k * h)


def _cell_weights(
    cells: Sequence[ComCell | DecomCell], k: int, h: int, x_rows: list, e_rows: list, biases: list
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """``(w1, w2, b2, gamma, beta)`` per cell of k gated inputs; the x and e columns go to the stacks.

    The first layer reads ``[rec ((k-1)H); x; e]`` (ComCell k = 3: ``[v; h; x; e]``, DecomCell k = 2:
    ``[p; x; e]``); the second layer's rows ``[g (kH); c (H)]`` are permuted to ``[c; g]``.
    """
    rec, g = (k - 1) * h, k * h
    w1s, w2s, b2s, gammas, betas = [], [], [], [], []
    for cell in cells:
        w1 = _np(cell.fc1.weight)
        w1s.append(_f32(w1[:, :rec]))
        x_rows.append(w1[:, rec : rec + h])
        e_rows.append(w1[:, rec + h :])
        biases.append(_np(cell.fc1.bias))
        w2, b2 = _np(cell.fc2.weight), _np(cell.fc2.bias)
        w2s.append(_f32(np.concatenate([w2[g:], w2[:g]])))
        b2s.append(_f32(np.concatenate([b2[g:], b2[:g]])))
        gammas.append(_f32(0.5 * _np(cell.gate_norm.weight)))
        betas.append(_f32(0.5 * _np(cell.gate_norm.bias)))
    return w1s, w2s, b2s, gammas, betas


class NumpyStepper:
    """Weights, buffers and memory of one batch-1 numpy stepper (see the module docstring)."""

    def __init__(self, policy: OMPNPolicy) -> None:
        cfg = policy.config
        self.n, self.h, self.a = cfg.n_slots, cfg.slot_size, cfg.action_dim
        self.paper_update = cfg.memory_update == "paper"
        self.no_bottom_up = cfg.no_bottom_up
        self.no_top_down = cfg.no_top_down
        self.no_recurrence = cfg.no_bottom_up_recurrence
        self.discrete = cfg.action_type == "discrete"
        self._load_encoder(policy)
        x_rows: list[np.ndarray] = []
        e_rows: list[np.ndarray] = []
        biases: list[np.ndarray] = []
        self.com_w1, self.com_w2, self.com_b2, self.com_gamma, self.com_beta = _cell_weights(
            policy.com_list, 3, self.h, x_rows, e_rows, biases
        )
        self.dec_w1, self.dec_w2, self.dec_b2, self.dec_gamma, self.dec_beta = _cell_weights(
            policy.decom_list, 2, self.h, x_rows, e_rows, biases
        )
        self._load_score_and_head(policy, x_rows, e_rows, biases)
        self._stack_projections(cfg.obs_dim, x_rows, e_rows, biases)
        self._allocate_buffers()

    def _load_encoder(self, policy: OMPNPolicy) -> None:
        """The encoder with the observation normalisation folded in: ``x = enc_w s + enc_b``."""
        w_in, b_in = _np(policy.encoder.weight), _np(policy.encoder.bias)
        mean, scale = _np(policy.obs_mean), _np(policy.obs_scale)
        enc_w = w_in / scale[None, :]
        self.enc_w = _f32(enc_w)  # [H, D]
        self.enc_wt = _f32(enc_w.T)  # [D, H]: rows gathered for sparse observations
        self.enc_b = _f32(b_in - enc_w @ mean)
        self.mean_is_zero = not mean.any()  # sparse gather needs (s - mean) sparse, i.e. mean = 0

    def _load_score_and_head(self, policy: OMPNPolicy, x_rows: list, e_rows: list, biases: list) -> None:
        """The score MLP's and the action head's own columns; their x and e columns go to the stacks."""
        h = self.h
        s1 = _np(policy.score.fc1.weight)  # [H, 4H] on [x; e; m; c]
        x_rows.append(s1[:, :h])
        e_rows.append(s1[:, h : 2 * h])
        biases.append(_np(policy.score.fc1.bias))
        self.score_mc = _f32(s1[:, 2 * h :].T)  # [2H, H] on rows [m; c]
        self.score_w2 = _np(policy.score.fc2.weight)[0]
        self.score_b2 = float(_np(policy.score.fc2.bias)[0])
        wa, ba = policy.head_params(policy.head)  # [A, 3H] on [O; e; x], action norm folded in
        self.head_o = _f32(wa[:, :h])
        x_rows.append(wa[:, 2 * h :])
        e_rows.append(wa[:, h : 2 * h])
        biases.append(ba)

    def _stack_projections(self, obs_dim: int, x_rows: list, e_rows: list, biases: list) -> None:
        """One matrix for every x-column block (``x_proj``), one for the e columns, one bias."""
        self.x_proj = _f32(np.concatenate(x_rows, axis=0))  # [R, H]
        self.e_proj = _f32(np.concatenate(e_rows, axis=0))
        self.bias = _f32(np.concatenate(biases))
        # Small observations (Dial: 39 < m): project s directly with x_proj @ W_in (R x D instead of
        # R x m), composed in float64 to keep the rounding of one product.
        self.obs_proj: np.ndarray | None = None
        if obs_dim < self.h:
            x_proj64 = self.x_proj.astype(np.float64)
            self.obs_proj = _f32(x_proj64 @ self.enc_w.astype(np.float64))
            self.bias = _f32(self.bias + x_proj64 @ self.enc_b)

    def _allocate_buffers(self) -> None:
        """Buffers and memory; views are created once here, so a step only calls numpy kernels."""
        n, h, a = self.n, self.h, self.a
        self.x = np.empty(h, np.float32)
        self.proj = np.empty(self.x_proj.shape[0], np.float32)
        self.const = self.bias.copy()
        self.com_pre = [self.proj[4 * h * i : 4 * h * (i + 1)] for i in range(n)]
        self.dec_pre = [self.proj[4 * h * (n + k) : 4 * h * (n + k + 1)] for k in range(n - 1)]
        off = 4 * h * (2 * n - 1)
        self.score_pre = self.proj[off : off + h]
        self.head_pre = self.proj[off + h : off + h + a]
        self.hidden = np.empty(4 * h, np.float32)
        self.com_views = _CellViews(h, 3)  # [v; h; c; g_v g_h g_c]
        self.dec_views = _CellViews(h, 2)  # [p; c; g_p g_c]
        self.ones1 = np.ones(h, np.float32)
        self.inv_h = 1.0 / h
        self.score_in = np.empty((n, 2 * h), np.float32)  # rows [M^{t-1}_i; C_i]
        self.score_hidden = np.empty((n, h), np.float32)
        self.mix = np.empty(h, np.float32)
        self.memory = np.zeros((n, h), np.float32)
        self.next_memory = np.zeros((n, h), np.float32)
        self.cand = np.zeros((n, h), np.float32)
        self.m_hat = np.zeros((n, h), np.float32)
        self.cand_rows = list(self.cand)
        self.m_hat_rows = list(self.m_hat)
        self.action = np.empty(a, np.float32)
        self.first = True

    def reset(self, task_emb: np.ndarray, memory0: np.ndarray) -> None:
        """New episode: fold e into the constant projection and load M^0 (``[n, m]``)."""
        self.const = self.bias + self.e_proj @ task_emb if task_emb.any() else self.bias.copy()
        self.memory[...] = memory0
        self.first = True

    def _encode(self, s: np.ndarray) -> None:
        """``proj = [all x-column blocks] @ x + const`` and ``x = W_in (s - mean) / scale + b_in``."""
        if self.obs_proj is not None:
            np.dot(self.enc_w, s, out=self.x)
            self.x += self.enc_b
            np.dot(self.obs_proj, s, out=self.proj)
        else:
            nz = np.flatnonzero(s) if self.mean_is_zero else None
            if nz is not None and nz.size <= SPARSE_FRACTION * s.size:
                np.dot(s[nz], self.enc_wt[nz], out=self.x)
            else:
                np.dot(self.enc_w, s, out=self.x)
            self.x += self.enc_b
            np.dot(self.x_proj, self.x, out=self.proj)
        self.proj += self.const

    def _gated_norm(self, views: _CellViews, gamma: np.ndarray, beta: np.ndarray, out: np.ndarray) -> None:
        """``out = LN(sum_j sigmoid(LN_aff(g)_j) * in_j)`` (the cells' gated sum and output norm).

        ``views.inputs`` holds the k gated inputs (``[v; h; c]`` or ``[p; c]``), ``views.gates`` the
        k gate pre-activations.
        """
        g, mix = views.gates, self.mix
        inv_n = views.inv_gates
        g -= float(np.dot(g, views.ones)) * inv_n
        g *= 1.0 / math.sqrt(float(np.dot(g, g)) * inv_n + LN_EPS)
        g *= gamma
        g += beta
        np.tanh(g, out=g)
        g += 1.0  # 2 sigmoid(y) = 1 + tanh(y / 2); the factor 2 cancels in the LayerNorm below
        g *= views.inputs
        rows = views.gate_rows
        np.add(rows[0], rows[1], out=mix)
        for row in rows[2:]:
            mix += row
        mix -= float(np.dot(mix, self.ones1)) * self.inv_h
        np.multiply(mix, 1.0 / math.sqrt(float(np.dot(mix, mix)) * self.inv_h + 4.0 * LN_EPS), out=out)

    def _bottom_up(self) -> None:
        views, hidden = self.com_views, self.hidden
        below = self.x
        for i in range(self.n):
            if not self.no_recurrence:
                np.copyto(views.first, below)  # v = C_{i-1} (stays 0 for the ablation)
            np.copyto(views.second, self.memory[i])
            np.dot(self.com_w1[i], views.rec, out=hidden)
            hidden += self.com_pre[i]
            np.maximum(hidden, 0.0, out=hidden)
            np.dot(self.com_w2[i], hidden, out=views.z)
            views.z += self.com_b2[i]
            below = self.cand_rows[i]
            self._gated_norm(views, self.com_gamma[i], self.com_beta[i], below)

    def _scores(self) -> list[float]:
        h = self.h
        self.score_in[:, :h] = self.memory
        self.score_in[:, h:] = self.cand
        hid = self.score_hidden
        np.dot(self.score_in, self.score_mc, out=hid)
        hid += self.score_pre
        np.maximum(hid, 0.01 * hid, out=hid)  # LeakyReLU(0.01)
        return (hid @ self.score_w2 + self.score_b2).tolist()

    def _top_down(self, rcp: list[float]) -> None:
        views, hidden = self.dec_views, self.hidden
        self.m_hat.fill(0.0)
        if self.no_top_down:
            return
        parent = views.first
        for i in range(self.n - 1, 0, -1):
            r = rcp[i]
            if r == 1.0:
                np.copyto(parent, self.cand_rows[i])
            else:
                np.multiply(self.cand_rows[i], r, out=parent)
                if i < self.n - 1:  # M_hat_n = 0
                    parent += (1.0 - r) * self.m_hat_rows[i]
            k = i - 1
            np.dot(self.dec_w1[k], parent, out=hidden)
            hidden += self.dec_pre[k]
            np.maximum(hidden, 0.0, out=hidden)
            np.dot(self.dec_w2[k], hidden, out=views.z)
            views.z += self.dec_b2[k]
            self._gated_norm(views, self.dec_gamma[k], self.dec_beta[k], self.m_hat_rows[k])

    def step(self, s: np.ndarray) -> tuple[np.ndarray, list[float], float, list[float]]:
        """One step on a float32 observation; returns ``(action_out, pi_hat, pi_end, pi)``.

        ``action_out`` is an internal buffer, valid until the next call.
        """
        n = self.n
        self._encode(s)
        if self.first or self.no_bottom_up:
            self.cand[...] = self.memory
        else:
            self._bottom_up()
        if self.first:
            pi_hat = [0.0] * (n - 1) + [1.0]
            pi_end = 0.0
        else:
            pi_hat, survive = [], 1.0
            for logit in self._scores():  # stick-breaking, lowest slot first (float64 scalars)
                beta = 1.0 / (1.0 + math.exp(-logit))
                pi_hat.append(beta * survive)
                survive *= 1.0 - beta
            pi_end = survive
        total = max(sum(pi_hat), 1e-12)
        pi = [p / total for p in pi_hat]
        rcp, acc = [], 0.0
        for p in pi:
            acc += p
            rcp.append(acc)
        self._top_down(rcp)

        new = self.next_memory
        if self.paper_update:  # M^t = M^{t-1}(1 - cp) + C pi + M_hat(1 - rcp), cp_i = 1 - rcp_i + pi_i
            keep, take, keep_hat = np.array(
                [[r - p for r, p in zip(rcp, pi, strict=True)], pi, [1.0 - r for r in rcp]], dtype=np.float32
            )[:, :, None]
            np.multiply(self.memory, keep, out=new)
            new += self.cand * take
        else:  # M^t = rcp C + (1 - rcp) M_hat
            take, keep_hat = np.array([rcp, [1.0 - r for r in rcp]], dtype=np.float32)[:, :, None]
            np.multiply(self.cand, take, out=new)
        new += self.m_hat * keep_hat
        self.memory, self.next_memory = new, self.memory
        self.first = False
        np.dot(self.head_o, new[0], out=self.action)
        self.action += self.head_pre
        return self.action, pi_hat, pi_end, pi
