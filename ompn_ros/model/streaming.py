"""StreamingPolicy: stateful batch-1 OMPN stepping with numpy in and out (live node, replay).

Two backends share the weights of one :class:`OMPNPolicy`:

* ``'numpy'`` (default): a float32 numpy re-implementation of :meth:`OMPNPolicy.step` with the
  weights copied and pre-sliced at construction.  Everything that depends only on the episode (the
  task embedding's contribution to every layer) is computed once in :meth:`reset`, the observation
  normalisation is folded into the encoder, and all projections of x are one matrix-vector product.
* ``'torch'``: the eager :meth:`OMPNPolicy.step` under ``torch.inference_mode`` (the reference).

The two agree to float32 rounding (tested to 1e-5).  Weights are copied at construction: later
changes to the module are not seen (build a new StreamingPolicy after training).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from scipy.special import expit

from ompn_ros.model.cells import LN_EPS
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.policy import MemoryState, ModelInputError, OMPNPolicy

Backend = Literal["numpy", "torch"]


class StreamingInputError(ModelInputError):
    """Bad input to :class:`StreamingPolicy` (wrong observation size, missing sketch, ...)."""


@dataclass(frozen=True)
class StepOutput:
    """One streaming step.

    Attributes:
        action: discrete: argmax over the env actions (int, done excluded); continuous: the Gaussian
            mean (float32 ``[A]``).
        pi: ``[n]`` normalised expansion distribution, lowest slot first.
        pi_end: probability that every subtask is finished (paper pi_end).
        p_hat: ``[n+1]`` ordered [pi_end, slot n (top), ..., slot 1], sums to 1.
        expected_position: ``sum_i i pi_i`` for i = 1..n (paper pi_avg).
        done_prob: p'(done) = pi_end.
    """

    action: np.ndarray | int
    pi: np.ndarray
    pi_end: float
    p_hat: np.ndarray
    expected_position: float
    done_prob: float


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def _layer_norm(z: np.ndarray, ones: np.ndarray) -> np.ndarray:
    """LayerNorm without affine; ``ones`` is a float32 vector of z's size (BLAS dots beat mean/var)."""
    inv_n = 1.0 / z.size
    d = z - float(np.dot(z, ones)) * inv_n
    return d * (1.0 / math.sqrt(float(np.dot(d, d)) * inv_n + LN_EPS))


class _NumpyWeights:
    """Weights of one policy, sliced by input block for the batch-1 step (see ``cells.py``)."""

    def __init__(self, policy: OMPNPolicy) -> None:
        cfg = policy.config
        n, h, a = cfg.n_slots, cfg.slot_size, cfg.action_dim
        self.n, self.h = n, h
        w_in, b_in = _np(policy.encoder.weight), _np(policy.encoder.bias)
        mean, scale = _np(policy.obs_mean), _np(policy.obs_scale)
        self.enc_w = np.ascontiguousarray(w_in / scale[None, :])
        self.enc_b = (b_in - self.enc_w @ mean).astype(np.float32)

        x_rows, e_rows, biases = [], [], []
        self.com_vh, self.com_h, self.com_w2, self.com_b2, self.com_gamma, self.com_beta = (
            [],
            [],
            [],
            [],
            [],
            [],
        )
        for cell in policy.com_list:
            w1 = _np(cell.fc1.weight)  # [4H, 4H] on [v; h; x; e]
            self.com_vh.append(np.ascontiguousarray(w1[:, : 2 * h]))
            self.com_h.append(np.ascontiguousarray(w1[:, h : 2 * h]))
            x_rows.append(w1[:, 2 * h : 3 * h])
            e_rows.append(w1[:, 3 * h :])
            biases.append(_np(cell.fc1.bias))
            self.com_w2.append(_np(cell.fc2.weight))
            self.com_b2.append(_np(cell.fc2.bias))
            self.com_gamma.append(_np(cell.gate_norm.weight))
            self.com_beta.append(_np(cell.gate_norm.bias))
        self.dec_p, self.dec_w2, self.dec_b2, self.dec_gamma, self.dec_beta = [], [], [], [], []
        for dcell in policy.decom_list:
            w1 = _np(dcell.fc1.weight)  # [4H, 3H] on [p; x; e]
            self.dec_p.append(np.ascontiguousarray(w1[:, :h]))
            x_rows.append(w1[:, h : 2 * h])
            e_rows.append(w1[:, 2 * h :])
            biases.append(_np(dcell.fc1.bias))
            self.dec_w2.append(_np(dcell.fc2.weight))
            self.dec_b2.append(_np(dcell.fc2.bias))
            self.dec_gamma.append(_np(dcell.gate_norm.weight))
            self.dec_beta.append(_np(dcell.gate_norm.bias))
        s1 = _np(policy.score.fc1.weight)  # [H, 4H] on [x; e; m; c]
        x_rows.append(s1[:, :h])
        e_rows.append(s1[:, h : 2 * h])
        biases.append(_np(policy.score.fc1.bias))
        self.score_mc = np.ascontiguousarray(s1[:, 2 * h :].T)  # [2H, H] for rows [m; c]
        self.score_w2 = _np(policy.score.fc2.weight)[0]
        self.score_b2 = float(_np(policy.score.fc2.bias)[0])
        wa = _np(policy.head.weight)  # [A, 3H] on [O; e; x]
        self.head_o = np.ascontiguousarray(wa[:, :h])
        x_rows.append(wa[:, 2 * h :])
        e_rows.append(wa[:, h : 2 * h])
        biases.append(_np(policy.head.bias))
        self.x_proj = np.ascontiguousarray(np.concatenate(x_rows, axis=0))
        self.e_proj = np.ascontiguousarray(np.concatenate(e_rows, axis=0))
        self.bias = np.concatenate(biases).astype(np.float32)
        # Small observations (Dial: 39 < m): project s directly with the composed matrix x_proj @ W_in
        # (R x D instead of R x m); composed in float64 to keep the rounding of one product.
        self.obs_proj: np.ndarray | None = None
        if cfg.obs_dim < h:
            composed = self.x_proj.astype(np.float64) @ self.enc_w.astype(np.float64)
            self.obs_proj = np.ascontiguousarray(composed.astype(np.float32))
            self.bias = (self.bias + self.x_proj.astype(np.float64) @ self.enc_b).astype(np.float32)
        bounds = np.cumsum([0] + [4 * h] * (2 * n - 1) + [h, a]).tolist()
        blocks = [slice(lo, hi) for lo, hi in itertools.pairwise(bounds)]
        self.com_slices, self.dec_slices = blocks[:n], blocks[n : 2 * n - 1]
        self.score_slice, self.head_slice = blocks[2 * n - 1], blocks[2 * n]
        self.ones = {k * h: np.ones(k * h, dtype=np.float32) for k in (1, 2, 3)}
        self.zero = np.zeros(h, dtype=np.float32)
        self.zero.flags.writeable = False


class StreamingPolicy:
    """Stateful, batch-1, no-autograd OMPN stepping; see the module docstring."""

    def __init__(self, policy: OMPNPolicy, backend: Backend = "numpy") -> None:
        if backend not in ("numpy", "torch"):
            raise StreamingInputError(f"backend must be 'numpy' or 'torch', got {backend!r}")
        self.policy = policy  # no dropout or batch norm: train/eval mode does not matter
        self.config: OMPNConfig = policy.config
        self.backend = backend
        self._w = _NumpyWeights(policy) if backend == "numpy" else None
        self._ready = False
        self._state: MemoryState | None = None
        if self.config.sketch_mode == "none":
            self.reset()

    @classmethod
    def from_checkpoint(cls, path: str | Path, backend: Backend = "numpy") -> StreamingPolicy:
        from ompn_ros.model.checkpoint import load_checkpoint

        policy, _ = load_checkpoint(path)
        return cls(policy, backend=backend)

    def reset(self, sketch: np.ndarray | None = None) -> None:
        """Start a new episode (initial memory M^0; the next step is the hard-coded first step)."""
        sketch_t = None
        if sketch is not None:
            arr = np.asarray(sketch)
            if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
                raise StreamingInputError(
                    f"sketch must be a 1-D integer array [K], got {arr.shape} {arr.dtype}"
                )
            sketch_t = torch.as_tensor(arr.astype(np.int64)).unsqueeze(0)
        with torch.inference_mode():
            state = self.policy.initial_state(1, sketch_t)
        self._state = state
        if self._w is not None:
            w = self._w
            e = _np(state.task_emb[0])
            self._const = w.bias + w.e_proj @ e
            self._memory = [m.copy() for m in _np(state.memory[0])]
            self._first = True
        self._ready = True

    def _check(self, obs: np.ndarray) -> np.ndarray:
        if not self._ready:
            raise StreamingInputError("this model has sketch_mode='sum': call reset(sketch) before step()")
        arr = np.asarray(obs, dtype=np.float32).reshape(-1)
        if arr.size != self.config.obs_dim:
            raise StreamingInputError(
                f"observation has {np.asarray(obs).size} values, "
                f"the model expects obs_dim={self.config.obs_dim}"
            )
        if not np.isfinite(arr).all():
            raise StreamingInputError("observation contains NaN or inf")
        return arr

    def step(self, obs: np.ndarray) -> StepOutput:
        """Advance the memory by one observation and return the action and expansion distribution."""
        arr = self._check(obs)
        if self._w is None:
            return self._step_torch(arr)
        return self._step_numpy(arr)

    def _finish(
        self, action_out: np.ndarray, pi_hat: Sequence[float], pi_end: float, pi: Sequence[float]
    ) -> StepOutput:
        pi_arr = np.array(pi, dtype=np.float32)
        p_hat = np.array([pi_end, *pi_hat[::-1]], dtype=np.float32)
        if self.config.action_type == "discrete":
            action: np.ndarray | int = int(np.argmax(action_out))
        else:
            action = action_out.astype(np.float32)
        return StepOutput(
            action=action,
            pi=pi_arr,
            pi_end=float(pi_end),
            p_hat=p_hat,
            expected_position=float(sum(k * p for k, p in enumerate(pi, start=1))),
            done_prob=float(pi_end),
        )

    def _step_torch(self, arr: np.ndarray) -> StepOutput:
        assert self._state is not None
        with torch.inference_mode():
            out, self._state = self.policy.step(torch.from_numpy(arr).unsqueeze(0), self._state)
        pi_hat = out.p_hat[0, 1:].flip(0).tolist()
        return self._finish(out.action_out[0].numpy(), pi_hat, float(out.pi_end[0]), out.pi[0].tolist())

    def _step_numpy(self, s: np.ndarray) -> StepOutput:
        w = self._w
        assert w is not None
        cfg = self.config
        n, h = w.n, w.h
        ones1, ones2, ones3 = w.ones[h], w.ones[2 * h], w.ones[3 * h]
        x = w.enc_w @ s + w.enc_b
        proj = (w.x_proj @ x if w.obs_proj is None else w.obs_proj @ s) + self._const
        m_prev = self._memory

        if self._first or cfg.no_bottom_up:
            cand = m_prev
        else:
            cand, below = [], x
            for i in range(n):
                h_i = m_prev[i]
                pre = proj[w.com_slices[i]]
                if cfg.no_bottom_up_recurrence:
                    pre = pre + w.com_h[i] @ h_i
                    v = w.zero
                else:
                    pre = pre + w.com_vh[i] @ np.concatenate((below, h_i))
                    v = below
                z = w.com_w2[i] @ np.maximum(pre, 0.0) + w.com_b2[i]
                g = expit(_layer_norm(z[: 3 * h], ones3) * w.com_gamma[i] + w.com_beta[i])
                below = _layer_norm(g[:h] * v + g[h : 2 * h] * h_i + g[2 * h :] * z[3 * h :], ones1)
                cand.append(below)

        if self._first:
            pi_hat = [0.0] * (n - 1) + [1.0]
            pi_end = 0.0
        else:
            hidden = np.concatenate((np.stack(m_prev), np.stack(cand)), axis=1) @ w.score_mc
            hidden += proj[w.score_slice]
            hidden = np.maximum(hidden, 0.01 * hidden)  # LeakyReLU(0.01)
            logits = (hidden @ w.score_w2 + w.score_b2).tolist()
            pi_hat, survive = [], 1.0
            for logit in logits:  # stick-breaking, lowest slot first (float64 scalars)
                beta = 1.0 / (1.0 + math.exp(-logit))
                pi_hat.append(beta * survive)
                survive *= 1.0 - beta
            pi_end = survive
        total = max(sum(pi_hat), 1e-12)
        pi = [p / total for p in pi_hat]
        rcp = list(itertools.accumulate(pi))

        m_hat = [w.zero] * n
        if not cfg.no_top_down:
            for i in range(n - 1, 0, -1):
                r = rcp[i]
                parent = cand[i] if r == 1.0 else r * cand[i] + (1.0 - r) * m_hat[i]
                k = i - 1
                pre = proj[w.dec_slices[k]] + w.dec_p[k] @ parent
                z = w.dec_w2[k] @ np.maximum(pre, 0.0) + w.dec_b2[k]
                g = expit(_layer_norm(z[: 2 * h], ones2) * w.dec_gamma[k] + w.dec_beta[k])
                m_hat[k] = _layer_norm(g[:h] * parent + g[h:] * z[2 * h :], ones1)

        if cfg.memory_update == "paper":
            memory = []
            for i in range(n):
                cp_i = 1.0 - rcp[i] + pi[i]
                memory.append(m_prev[i] * (1.0 - cp_i) + cand[i] * pi[i] + m_hat[i] * (1.0 - rcp[i]))
        else:
            memory = [rcp[i] * cand[i] + (1.0 - rcp[i]) * m_hat[i] for i in range(n)]
        self._memory = memory  # float32: python-float scalars do not promote (NEP 50)
        self._first = False
        action_out = w.head_o @ self._memory[0] + proj[w.head_slice]
        return self._finish(action_out, pi_hat, pi_end, pi)
