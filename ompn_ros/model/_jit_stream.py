"""Compiled batch-1 OMPN step (the ``'jit'`` backend of ``streaming.py``, via numba).

The numpy kernel (:mod:`ompn_ros.model._fast_stream`) spends much of a step in the fixed cost of
each of its many numpy calls; the matrix-vector products themselves are bound by reading the weights
(the figures: docs/design.md#fast-model-paths).  Here the whole step is one compiled
call: same weights (prepared by :class:`~ompn_ros.model._fast_stream.NumpyStepper`, stacked per cell
kind), same arithmetic (paper §3.1 and appendix A: bottom-up ComCells, stick-breaking π, top-down
DecomCells, the memory update of Eq. (2) or the authors' code), the matrix-vector products through
BLAS (``np.dot``) or compiled loops (the cells and the score, whose matrices are read as float16
when the checkpoint's weights are float16 values, halving the memory traffic), the rest as plain
loops.

Compilation happens once per machine (``cache=True`` keeps the machine code next to this file, or in
numba's user cache when that is read-only) and is triggered by :meth:`JitStepper.warm_up`, so a node
pays it in ``on_configure``, never on its first message.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ompn_ros.model._fast_stream import SPARSE_FRACTION, NumpyStepper
from ompn_ros.model.cells import LN_EPS
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.policy import OMPNPolicy


@intrinsic
def _as_f32(typingctx, value):  # type: ignore[no-untyped-def]
    """A weight as float32: float32 as is; uint16 read as IEEE half and widened (exact, F16C on x86)."""
    if isinstance(value, types.Float) and value.bitwidth == 32:
        return types.float32(value), lambda context, builder, sig, args: args[0]
    if isinstance(value, types.Integer) and value.bitwidth == 16:

        def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
            return builder.fpext(builder.bitcast(args[0], ir.HalfType()), ir.FloatType())

        return types.float32(value), codegen
    return None


@njit(cache=True, fastmath=True)
def _matvec(w: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = W v`` for row-major ``w`` of float32 or float16 bits (uint16); the compiler vectorises
    the widening, so half weights cost half the memory traffic and no extra time."""
    for j in range(w.shape[0]):
        acc = np.float32(0.0)
        for k in range(w.shape[1]):
            acc += _as_f32(w[j, k]) * v[k]  # type: ignore[call-arg]  # numba intrinsic
        out[j] = acc


@njit(cache=True, fastmath=True, inline="always")
def _mean_inv_std(a: np.ndarray, eps: float) -> tuple[np.float32, np.float32]:
    """Mean of ``a`` and ``1 / sqrt(var + eps)`` (biased variance, as LayerNorm), in float32."""
    n = np.float32(a.shape[0])
    mean = np.float32(0.0)
    for j in range(a.shape[0]):
        mean += a[j]
    mean /= n
    var = np.float32(0.0)
    for j in range(a.shape[0]):
        d = a[j] - mean
        var += d * d
    return mean, np.float32(1.0) / np.sqrt(var / n + np.float32(eps))


@njit(cache=True, fastmath=True, inline="always")
def _gated_norm(
    buf: np.ndarray, k: int, h: int, gamma: np.ndarray, beta: np.ndarray, out: np.ndarray
) -> None:
    """``out = LN(sum_j sigmoid(LN_aff(g)_j) * in_j)``; ``buf = [in_1 .. in_k; g_1 .. g_k]``.

    ``gamma``/``beta`` are pre-halved so that ``1 + tanh`` = 2 sigmoid; the factor 2 is absorbed by the
    final (scale-invariant) LayerNorm, whose eps is multiplied by 4 to match.  float32 throughout, as
    in the numpy kernel (fastmath only reorders the sums).
    """
    kh = k * h
    gates = buf[kh : 2 * kh]
    mean, inv = _mean_inv_std(gates, LN_EPS)
    for j in range(kh):
        gates[j] = np.tanh((gates[j] - mean) * inv * gamma[j] + beta[j])
    for j in range(h):
        out[j] = (np.float32(1.0) + gates[j]) * buf[j]
    for r in range(1, k):
        for j in range(h):
            out[j] += (np.float32(1.0) + gates[r * h + j]) * buf[r * h + j]
    mean, inv = _mean_inv_std(out, 4.0 * LN_EPS)
    for j in range(h):
        out[j] = (out[j] - mean) * inv


@njit(cache=True, inline="always")
def _relu_matvec(w_t: np.ndarray, hidden: np.ndarray, bias: np.ndarray, out: np.ndarray) -> None:
    """``out = W hidden + bias`` for a ReLU output ``hidden``, with ``w_t = W^T`` (float32 or float16
    bits): only the rows of the active (non-zero) units are read, about half of the weights."""
    for j in range(out.shape[0]):
        out[j] = bias[j]
    for k in range(hidden.shape[0]):
        hk = hidden[k]
        if hk != 0.0:
            row = w_t[k]
            for j in range(out.shape[0]):
                out[j] += hk * _as_f32(row[j])  # type: ignore[call-arg]


@njit(cache=True)
def _step(
    s, first, flags, enc_w, enc_wt, enc_b, obs_proj, x_proj, sparse_proj_t, sparse_bias, const,
    com_w1, com_w2_t, com_b2, com_gamma, com_beta, dec_w1, dec_w2_t, dec_b2, dec_gamma, dec_beta,
    score_mc_t, score_w2, score_b2, head_o,
    memory, next_memory, cand, m_hat, x, proj, com_buf, dec_buf, hidden, score_in, action, probs,
):  # pragma: no cover - compiled; checked against the torch reference in the tests
    """One step; writes ``next_memory``, ``action`` and ``probs = [pi_hat (n); pi (n); pi_end]``."""
    n, h = memory.shape
    a = action.shape[0]
    paper_update, no_bottom_up, no_top_down, no_recurrence, use_obs_proj, mean_is_zero = (
        flags[0], flags[1], flags[2], flags[3], flags[4], flags[5]
    )
    # encoder and all projections of x (const holds the biases and the task embedding's share)
    if use_obs_proj:
        x[:] = np.dot(enc_w, s)
        for j in range(h):
            x[j] += enc_b[j]
        proj[:] = np.dot(obs_proj, s)
    else:
        nnz = 0
        if mean_is_zero:  # the gather needs s - mean to be sparse, i.e. mean = 0
            for j in range(s.shape[0]):
                if s[j] != 0.0:
                    nnz += 1
        if mean_is_zero and nnz <= SPARSE_FRACTION * s.shape[0]:
            # Sparse (Craft one-hot): gather the non-zero rows of W_in^T for x and of the composed
            # (x_proj W_in)^T for every projection of x, instead of reading all of x_proj.
            for j in range(h):
                x[j] = enc_b[j]
            for j in range(proj.shape[0]):
                proj[j] = sparse_bias[j]
            for i in range(s.shape[0]):
                si = s[i]
                if si != 0.0:
                    for j in range(h):
                        x[j] += si * enc_wt[i, j]
                    for j in range(proj.shape[0]):
                        proj[j] += si * sparse_proj_t[i, j]
        else:
            x[:] = np.dot(enc_w, s)
            for j in range(h):
                x[j] += enc_b[j]
            proj[:] = np.dot(x_proj, x)
    for j in range(proj.shape[0]):
        proj[j] += const[j]

    # bottom-up: C_i = ComCell_i(C_{i-1}, M^{t-1}_i, x)
    if first or no_bottom_up:
        cand[:, :] = memory
    else:
        for j in range(h):
            com_buf[j] = x[j] if not no_recurrence else 0.0
        for i in range(n):
            if i > 0 and not no_recurrence:
                for j in range(h):
                    com_buf[j] = cand[i - 1, j]
            for j in range(h):
                com_buf[h + j] = memory[i, j]
            _matvec(com_w1[i], com_buf[: 2 * h], hidden)
            for j in range(4 * h):
                v = hidden[j] + proj[4 * h * i + j]
                hidden[j] = v if v > 0.0 else 0.0
            _relu_matvec(com_w2_t[i], hidden, com_b2[i], com_buf[2 * h :])
            _gated_norm(com_buf, 3, h, com_gamma[i], com_beta[i], cand[i])

    # expansion distribution: stick-breaking over the slot scores, lowest slot first (float64)
    pi_end = 0.0
    if first:
        for i in range(n):
            probs[i] = 1.0 if i == n - 1 else 0.0
    else:
        off = 4 * h * (2 * n - 1)
        survive = 1.0
        for i in range(n):
            for j in range(h):
                score_in[i, j] = memory[i, j]
                score_in[i, h + j] = cand[i, j]
            score_hid = hidden[:h]  # free between the bottom-up and the top-down pass
            _matvec(score_mc_t, score_in[i], score_hid)
            logit = score_b2
            for j in range(h):
                v = score_hid[j] + proj[off + j]
                if v < 0.0:
                    v *= 0.01
                logit += v * score_w2[j]
            beta = 1.0 / (1.0 + math.exp(-logit))
            probs[i] = beta * survive
            survive *= 1.0 - beta
        pi_end = survive
    total = 0.0
    for i in range(n):
        total += probs[i]
    total = max(total, 1e-12)
    for i in range(n):
        probs[n + i] = probs[i] / total
    probs[2 * n] = pi_end

    # top-down: M_hat_{i-1} = DecomCell(rcp_i C_i + (1 - rcp_i) M_hat_i, x)
    m_hat[:, :] = 0.0
    rcp = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc += probs[n + i]
        rcp[i] = acc
    if not no_top_down:
        for i in range(n - 1, 0, -1):
            r = np.float32(rcp[i])
            rr = np.float32(1.0 - rcp[i])
            for j in range(h):
                p = cand[i, j] if rcp[i] == 1.0 else cand[i, j] * r
                if rcp[i] != 1.0 and i < n - 1:
                    p += rr * m_hat[i, j]
                dec_buf[j] = p
            k = i - 1
            _matvec(dec_w1[k], dec_buf[:h], hidden)
            for j in range(4 * h):
                v = hidden[j] + proj[4 * h * (n + k) + j]
                hidden[j] = v if v > 0.0 else 0.0
            _relu_matvec(dec_w2_t[k], hidden, dec_b2[k], dec_buf[h:])
            _gated_norm(dec_buf, 2, h, dec_gamma[k], dec_beta[k], m_hat[k])

    # memory update: Eq. (2) of the paper, or the update the authors' code ran
    for i in range(n):
        p_i = np.float32(probs[n + i])
        r = np.float32(rcp[i])
        keep_hat = np.float32(1.0 - rcp[i])
        if paper_update:
            keep = np.float32(rcp[i] - probs[n + i])
            for j in range(h):
                next_memory[i, j] = memory[i, j] * keep + cand[i, j] * p_i + m_hat[i, j] * keep_hat
        else:
            for j in range(h):
                next_memory[i, j] = cand[i, j] * r + m_hat[i, j] * keep_hat
    off = 4 * h * (2 * n - 1) + h
    action[:] = np.dot(head_o, next_memory[0])
    for j in range(a):
        action[j] += proj[off + j]


def _stack(arrays: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
    if not arrays:
        return np.zeros((0, *shape), np.float32)
    return np.ascontiguousarray(np.stack(arrays), dtype=np.float32)


def half_bits_if_exact(weights: list[np.ndarray]) -> list[np.ndarray] | None:
    """The float16 bit patterns (uint16) of ``weights`` when every value is a float16 exactly, else None.

    Checkpoints saved with ``weights_dtype='float16'`` (the shipped ones) satisfy this: the kernel
    then reads half the bytes for identical arithmetic, since widening float16 to float32 is exact.
    """
    halves = []
    for w in weights:
        with np.errstate(over="ignore"):  # out of float16 range -> inf -> not exact
            half = w.astype(np.float16)
        if not np.array_equal(half.astype(np.float32), w):
            return None
        halves.append(half.view(np.uint16))
    return halves


class JitStepper(NumpyStepper):
    """:class:`NumpyStepper`'s weights and memory, stepped by one compiled call."""

    def __init__(self, policy: OMPNPolicy) -> None:
        super().__init__(policy)
        n, h = self.n, self.h
        self._com = (
            _stack(self.com_w1, (4 * h, 2 * h)), _stack([w.T for w in self.com_w2], (4 * h, 4 * h)),
            _stack(self.com_b2, (4 * h,)), _stack(self.com_gamma, (3 * h,)), _stack(self.com_beta, (3 * h,)),
        )
        self._dec = (
            _stack(self.dec_w1, (4 * h, h)), _stack([w.T for w in self.dec_w2], (4 * h, 3 * h)),
            _stack(self.dec_b2, (3 * h,)), _stack(self.dec_gamma, (2 * h,)), _stack(self.dec_beta, (2 * h,)),
        )
        self._flags = np.array(
            [self.paper_update, self.no_bottom_up, self.no_top_down, self.no_recurrence,
             self.obs_proj is not None, self.mean_is_zero],
            dtype=np.bool_,
        )
        self._obs_proj = self.obs_proj if self.obs_proj is not None else np.zeros((1, 1), np.float32)
        # Sparse-capable inputs: (x_proj W_in)^T [D, R] composed in float64 (one rounding, as obs_proj)
        self._sparse_proj_t = np.zeros((1, 1), np.float32)
        self._sparse_bias = np.zeros(1, np.float32)
        if self.obs_proj is None and self.mean_is_zero:
            x_proj64 = self.x_proj.astype(np.float64)
            composed = x_proj64 @ self.enc_w.astype(np.float64)
            self._sparse_proj_t = np.ascontiguousarray(composed.T, np.float32)
            self._sparse_bias = (x_proj64 @ self.enc_b.astype(np.float64)).astype(np.float32)
        self._score_mc_t = np.ascontiguousarray(self.score_mc.T)  # [H, 2H]: one gemv per slot
        # The cells' and the score's matrices (> 90 % of the bytes a step reads) in float16 when exact
        big = [self._com[0], self._com[1], self._dec[0], self._dec[1], self._score_mc_t]
        halves = half_bits_if_exact(big)
        self.weights_dtype = "float16" if halves is not None else "float32"
        if halves is not None:
            com_w1, com_w2_t, dec_w1, dec_w2_t, self._score_mc_t = halves
            self._com = (com_w1, com_w2_t, *self._com[2:])
            self._dec = (dec_w1, dec_w2_t, *self._dec[2:])
        self._com_buf = np.zeros(6 * h, np.float32)
        self._dec_buf = np.zeros(4 * h, np.float32)
        self._probs = np.zeros(2 * n + 1, np.float64)

    def warm_up(self) -> None:
        """Compile (or load the cached machine code) now, leaving the memory as it was."""
        saved = (self.memory.copy(), self.first)
        self.step(np.zeros(self.enc_w.shape[1], np.float32))
        self.memory[...], self.first = saved

    def step(self, s: np.ndarray) -> tuple[np.ndarray, list[float], float, list[float]]:
        """Same contract as :meth:`NumpyStepper.step`."""
        _step(
            s, self.first, self._flags, self.enc_w, self.enc_wt, self.enc_b, self._obs_proj, self.x_proj,
            self._sparse_proj_t, self._sparse_bias, self.const, *self._com, *self._dec, self._score_mc_t,
            self.score_w2, self.score_b2, self.head_o,
            self.memory, self.next_memory, self.cand, self.m_hat, self.x, self.proj, self._com_buf,
            self._dec_buf, self.hidden, self.score_in, self.action, self._probs,
        )
        self.memory, self.next_memory = self.next_memory, self.memory
        self.first = False
        n = self.n
        probs = self._probs.tolist()
        return self.action, probs[:n], probs[2 * n], probs[n : 2 * n]


def main() -> None:
    """``python -m ompn_ros.model._jit_stream``: compile the kernel into numba's cache (``make setup``)."""
    start = time.perf_counter()
    for cfg in (
        OMPNConfig(obs_dim=40, action_type="discrete", action_dim=5, n_slots=2, slot_size=16),
        OMPNConfig(obs_dim=8, action_type="continuous", action_dim=3, n_slots=2, slot_size=16),
    ):
        for half in (False, True):  # float32 and float16-exact weights compile separately
            torch.manual_seed(0)
            policy = OMPNPolicy(cfg)
            if half:
                with torch.no_grad():
                    for p in policy.parameters():
                        p.copy_(p.half().float())
            JitStepper(policy).warm_up()
    print(f"ompn_ros: streaming kernel compiled in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
