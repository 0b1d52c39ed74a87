"""OMPNPolicy: the Ordered Memory Policy Network (Lu et al., ICLR 2021, §3 and appendix A).

Memory ``M`` has n slots of size m (``[B, n, m]``, index 0 = paper slot 1 = the *lowest* slot).
One step (paper §3.1, code branch "not initial", docs/craft.md §3.5):

1. ``x = W_in((s - mean) / scale) + b_in``; ``u = [x; e]`` with e the task (sketch) embedding.
2. Bottom-up: ``C_0 = x``; ``C_i = ComCell_i(C_{i-1}, M^{t-1}_i, u)`` for i = 1..n.
3. Scores ``beta_i = sigmoid(G([x; e; M^{t-1}_i; C_i])) = 1 - f_i``; stick-breaking:
   ``pi_hat_i = beta_i prod_{j<i} (1 - beta_j)``, ``pi_end = prod_j (1 - beta_j)``, ``pi = pi_hat / sum``;
   ``rcp_i = sum_{j<=i} pi_j``, ``cp_i = sum_{j>=i} pi_j``.
4. Top-down: ``M_hat_n = 0``; ``M_hat_{i-1} = DecomCell_i(rcp_i C_i + (1 - rcp_i) M_hat_i, u)``.
5. Memory update, ``memory_update='paper'`` (paper Eq. 2): ``M^t = M^{t-1}(1-cp) + C pi + M_hat(1-rcp)``;
   ``'code'`` (what the authors' code executes, docs/craft.md §3.5.4):
   ``M^t_i = rcp_i C_i + (1-rcp_i) M_hat_i``.
6. Output ``O = M^t_1``; action head ``W_a [O; e; x] + b_a`` (logits, or the Gaussian mean; with
   ``action_norm='standard'`` the head predicts standardised actions and the output is
   ``head * std + mean``, in the data's units).

Places where we follow the authors' code rather than the paper's text (docs/craft.md §3.10):

* First step (paper appendix A says only "skip bottom-up, expand from the top"): per sample, the
  bottom-up pass is skipped (``C := M^0``), the score MLP is not used, ``p_hat = [0, 1, 0, ..., 0]``
  (pi = one-hot(top slot)), and pi_end = 0 (clamped to 1e-9 in the loss).
* Initial memory: ``M^0_n = LN(e)`` (LayerNorm without affine), other slots 0.  The Dial code uses a
  second sketch encoder for this; we share the one embedding, as the Craft code does.
* Score MLP input ``[x; e; M^{t-1}_i; C_i]`` (paper: ``G(x, C_i, M^t_i)``), beta = 1 - f.
* Bottom-up starts from ``C_0 = x`` (not u), while every cell also reads ``u = [x; e]``.
* Action head on ``[O; e; x]`` with x the *encoded* observation (paper: ``[O; x]``).
* Only slots 2..n own a DecomCell: the code's DecomCell of slot 1 is computed and discarded, so we
  do not create it (the parameter count is 394 624 lower than the code's for n=3, m=128).
* Sketch embedding ``Embedding(vocab + 1, m)`` over ids + 1, summed over the sketch; id -1 pads (row 0) and
  contributes zero (deviation: the code learns a vector for the pad id too; ours makes the
  embedding independent of how much a batch pads the sketches).
* ``memory_update='paper'`` is the default; ``'code'`` reproduces the aliasing bug for comparison.

Ablations (paper §4.4): ``no_bottom_up`` (``C_i := M^{t-1}_i``), ``no_top_down`` (``M_hat := 0``),
``no_bottom_up_recurrence`` (ComCell_i gets ``v = 0``).

Two implementations share the weights: :meth:`OMPNPolicy.step` (eager, per slot, the reference)
and :meth:`OMPNPolicy.forward_sequence` (``impl='fused'``, the length-sorted fused training path in
``fused.py``; ``impl='reference'`` loops :meth:`step`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
import torch
from torch import Tensor, nn

from ompn_ros.model.cells import ComCell, DecomCell, ScoreMLP, plain_layer_norm
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ModelInputError
from ompn_ros.model.expansion import SequenceOutput, expansion_sums, stick_breaking, to_p_hat
from ompn_ros.model.fused import fused_forward_sequence


@dataclass
class MemoryState:
    """Recurrent state between steps.

    Attributes:
        memory: ``[B, n, m]``, index 0 = the lowest slot (paper M_1).
        first: ``[B]`` bool, True until the sample has taken its first step (paper's hard-coded pi^1).
        task_emb: ``[B, m]`` task embedding e (zeros without a sketch).
    """

    memory: Tensor
    first: Tensor
    task_emb: Tensor

    def detach(self) -> MemoryState:
        return MemoryState(self.memory.detach(), self.first, self.task_emb)


@dataclass
class StepTensors:
    """Outputs of one step: ``action_out [B, A]`` (logits or Gaussian mean), ``p_hat [B, n+1]``
    ordered [pi_end, slot n (top), ..., slot 1], ``pi [B, n]`` lowest slot first, ``pi_end [B]``."""

    action_out: Tensor
    p_hat: Tensor
    pi: Tensor
    pi_end: Tensor


def lengths_from_mask(mask: Tensor) -> Tensor:
    """Episode lengths from a ``[B, T]`` bool mask whose valid steps must form a prefix."""
    if mask.dim() != 2 or mask.dtype != torch.bool:
        raise ModelInputError(f"mask must be a [B, T] bool tensor, got {tuple(mask.shape)} {mask.dtype}")
    lengths = mask.sum(dim=1)
    prefix = torch.arange(mask.shape[1], device=mask.device).unsqueeze(0) < lengths.unsqueeze(1)
    if not torch.equal(prefix, mask):
        bad = int((prefix != mask).any(dim=1).nonzero()[0, 0])
        raise ModelInputError(
            f"mask row {bad} is not a prefix of valid steps (episodes must start at t=0 and padding "
            "must follow the last valid step)"
        )
    return lengths


class PolicyInputs:
    """Input handling shared by the OMPN and LSTM policies: sketch embedding and observation checks.

    Needs ``self.config`` (OMPNConfig), ``self.encoder`` (the observation Linear),
    ``self.sketch_embedding`` (``nn.Embedding(vocab + 1, m, padding_idx=0)`` or None) and the
    ``obs_mean`` / ``obs_scale`` buffers.
    """

    config: OMPNConfig
    encoder: nn.Linear
    sketch_embedding: nn.Embedding | None
    obs_mean: Tensor
    obs_scale: Tensor
    action_mean: Tensor
    action_std: Tensor

    def set_obs_normalization(self, mean: np.ndarray, scale: np.ndarray) -> None:
        """Store the observation normalisation applied inside the model: ``(obs - mean) / scale``."""
        d = self.config.obs_dim
        mean_t = torch.as_tensor(np.asarray(mean, dtype=np.float32)).reshape(-1)
        scale_t = torch.as_tensor(np.asarray(scale, dtype=np.float32)).reshape(-1)
        if mean_t.numel() != d or scale_t.numel() != d:
            raise ModelInputError(
                f"obs normalization needs mean and scale of size obs_dim={d}, got {mean_t.numel()} "
                f"and {scale_t.numel()}"
            )
        if not (torch.isfinite(mean_t).all() and torch.isfinite(scale_t).all() and (scale_t > 0).all()):
            raise ModelInputError("obs normalization: mean must be finite and scale finite and > 0")
        with torch.no_grad():
            self.obs_mean.copy_(mean_t)
            self.obs_scale.copy_(scale_t)

    def register_inputs(self) -> None:
        """The sketch embedding (``sketch_mode='sum'``, else None), the ``obs_mean`` / ``obs_scale``
        buffers and, with ``config.action_norm='standard'``, the buffers ``action_mean`` (zeros) and
        ``action_std`` (ones) of size ``action_dim`` (none otherwise: a checkpoint holds the tensors its
        config uses).  A policy's ``__init__`` calls it after its layers, so parameters keep their
        order and initialisation."""
        config, module = self.config, cast(nn.Module, self)
        self.sketch_embedding = None
        if config.sketch_mode == "sum":
            self.sketch_embedding = nn.Embedding(config.sketch_vocab + 1, config.slot_size, padding_idx=0)
        module.register_buffer("obs_mean", torch.zeros(config.obs_dim))
        module.register_buffer("obs_scale", torch.ones(config.obs_dim))
        if config.action_norm == "standard":
            module.register_buffer("action_mean", torch.zeros(config.action_dim))
            module.register_buffer("action_std", torch.ones(config.action_dim))

    def set_action_normalization(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Store the action standardisation of ``action_norm='standard'``: the head predicts
        ``(a - mean) / std`` and the model outputs actions in the data's units."""
        if self.config.action_norm != "standard":
            raise ModelInputError(f"action normalisation needs action_norm='standard', the config has "
                                  f"{self.config.action_norm!r}")
        a = self.config.action_dim
        mean_t = torch.as_tensor(np.asarray(mean, dtype=np.float32)).reshape(-1)
        std_t = torch.as_tensor(np.asarray(std, dtype=np.float32)).reshape(-1)
        if mean_t.numel() != a or std_t.numel() != a:
            raise ModelInputError(f"action normalisation needs mean and std of size action_dim={a}, got "
                                  f"{mean_t.numel()} and {std_t.numel()}")
        if not (torch.isfinite(mean_t).all() and torch.isfinite(std_t).all() and (std_t > 0).all()):
            raise ModelInputError("action normalisation: mean must be finite and std finite and > 0")
        with torch.no_grad():
            self.action_mean.copy_(mean_t)
            self.action_std.copy_(std_t)

    def action_scale(self) -> Tensor | None:
        """``action_std`` with ``action_norm='standard'`` (the loss divides residuals by it), else None."""
        return self.action_std if self.config.action_norm == "standard" else None

    def denormalize_action(self, head_out: Tensor) -> Tensor:
        """The Gaussian mean in the data's units: ``head_out * std + mean`` (identity without norm)."""
        if self.config.action_norm == "standard":
            return head_out * self.action_std + self.action_mean
        return head_out

    def head_params(self, head: nn.Linear) -> tuple[np.ndarray, np.ndarray]:
        """Weight ``[A, F]`` and bias ``[A]`` of ``head`` with the action normalisation folded in
        (float64), for kernels that apply the head themselves: ``W x + b`` is then in the data's units."""
        weight = head.weight.detach().cpu().double().numpy()
        bias = head.bias.detach().cpu().double().numpy()
        if self.config.action_norm == "standard":
            std = self.action_std.detach().cpu().double().numpy()
            mean = self.action_mean.detach().cpu().double().numpy()
            return weight * std[:, None], bias * std + mean
        return weight, bias

    def embed_sketch(self, sketch: Tensor | None, batch_size: int) -> Tensor:
        """Task embedding e ``[B, m]``: zeros (no sketch) or the sum of subtask embeddings."""
        ref = self.encoder.weight
        if self.sketch_embedding is None:
            if sketch is not None:
                raise ModelInputError("a sketch was given but the model has sketch_mode='none'")
            return ref.new_zeros(batch_size, self.config.slot_size)
        if sketch is None:
            raise ModelInputError("this model has sketch_mode='sum' and needs a sketch [B, K] int64")
        sketch = torch.as_tensor(sketch, device=ref.device)
        if sketch.dim() == 1:
            sketch = sketch.unsqueeze(0)
        if (
            sketch.dim() != 2
            or sketch.shape[0] != batch_size
            or sketch.dtype not in (torch.int64, torch.int32)
        ):
            raise ModelInputError(
                f"sketch must be an integer tensor [B={batch_size}, K], "
                f"got {tuple(sketch.shape)} {sketch.dtype}"
            )
        vocab = self.config.sketch_vocab
        if sketch.numel() and (int(sketch.min()) < -1 or int(sketch.max()) >= vocab):
            raise ModelInputError(
                f"sketch ids must lie in 0..{vocab - 1} (-1 = padding), got {sketch.tolist()}"
            )
        # Domain ids start at 0 (Dial digits), so the embedding table reserves row 0 for padding.
        return self.sketch_embedding(sketch.long() + 1).sum(dim=1)

    def forward_sequence(
        self,
        obs: Tensor,
        mask: Tensor,
        sketch: Tensor | None = None,
        bptt: int = 64,
        impl: Literal["fused", "reference"] = "fused",
        bf16: bool = False,
    ) -> SequenceOutput:
        """Run whole episodes from their first step (teacher forcing); padded steps of the output hold zeros.

        Args:
            obs: ``[B, T, D]`` float; padded steps may hold anything (they never affect valid steps).
            mask: ``[B, T]`` bool, valid steps; each row must be a prefix (episode starts at t=0).
            sketch: ``[B, K]`` int64 subtask ids (0 = padding), required iff sketch_mode='sum'.
            bptt: the memory is detached after every ``bptt`` steps (truncated BPTT).
            impl: ``'fused'`` (fast, length-sorted, fused matmuls) or ``'reference'`` (loops :meth:`step`);
                the LSTM accepts both and runs ``nn.LSTM`` for either.
            bf16: training speed option of the OMPN fused path: run the cell matmuls in bfloat16 autocast
                (outputs, memory, norms and the loss inputs stay float32; not for inference); the LSTM
                ignores it (it always runs in float32).
        """
        self._check_obs(obs, 3)
        return self._sequence(obs, mask, sketch, bptt, impl, bf16)

    def _sequence(
        self, obs: Tensor, mask: Tensor, sketch: Tensor | None, bptt: int, impl: str, bf16: bool
    ) -> SequenceOutput:
        raise NotImplementedError

    def _check_obs(self, obs: Tensor, ndim: int) -> None:
        if obs.dim() != ndim or obs.shape[-1] != self.config.obs_dim:
            want = "[B, D]" if ndim == 2 else "[B, T, D]"
            raise ModelInputError(
                f"obs must be {want} with D=obs_dim={self.config.obs_dim}, got shape {tuple(obs.shape)}"
            )
        if not obs.is_floating_point():
            raise ModelInputError(f"obs must be a float tensor, got {obs.dtype}")

    @staticmethod
    def _check_sequence(obs: Tensor, mask: Tensor, bptt: int) -> Tensor:
        """The episode lengths ``[B]`` of a ``forward_sequence`` call, its mask and bptt checked."""
        if mask.shape != obs.shape[:2]:
            raise ModelInputError(
                f"mask shape {tuple(mask.shape)} does not match obs [B, T] {tuple(obs.shape[:2])}"
            )
        if bptt <= 0:
            raise ModelInputError(f"bptt must be a positive number of steps, got {bptt}")
        return lengths_from_mask(mask)


class OMPNPolicy(PolicyInputs, nn.Module):
    """The OMPN policy; see the module docstring for the equations."""

    obs_mean: Tensor
    obs_scale: Tensor

    def __init__(self, config: OMPNConfig) -> None:
        super().__init__()
        self.config = config
        n, m = config.n_slots, config.slot_size
        self.encoder = nn.Linear(config.obs_dim, m)
        self.com_cells = nn.ModuleList([ComCell(m) for _ in range(n)])
        self.decom_cells = nn.ModuleList([DecomCell(m) for _ in range(n - 1)])  # slots 2..n
        self.score = ScoreMLP(m)
        self.head = nn.Linear(3 * m, config.action_dim)
        self.register_inputs()

    @property
    def com_list(self) -> list[ComCell]:
        """The bottom-up cells, slot 1 (lowest) first."""
        return [cast(ComCell, c) for c in self.com_cells]

    @property
    def decom_list(self) -> list[DecomCell]:
        """The top-down cells of slots 2..n: ``decom_list[k]`` produces M_hat_{k+1} from slot k+2."""
        return [cast(DecomCell, c) for c in self.decom_cells]

    # --- inputs -------------------------------------------------------------------------------------
    def encode_obs(self, obs: Tensor) -> Tensor:
        """x = W_in((s - mean) / scale) + b_in."""
        return self.encoder((obs - self.obs_mean) / self.obs_scale)

    # --- recurrence -----------------------------------------------------------------------------------
    def initial_state(self, batch_size: int, sketch: Tensor | None = None) -> MemoryState:
        """M^0: LN(e) in the top slot, zeros elsewhere; every sample starts with its first step."""
        e = self.embed_sketch(sketch, batch_size)
        memory = e.new_zeros(batch_size, self.config.n_slots, self.config.slot_size)
        memory = torch.cat([memory[:, :-1], plain_layer_norm(e).unsqueeze(1)], dim=1)
        first = torch.ones(batch_size, dtype=torch.bool, device=e.device)
        return MemoryState(memory=memory, first=first, task_emb=e)

    def step(
        self, obs: Tensor, state: MemoryState, sketch_emb: Tensor | None = None
    ) -> tuple[StepTensors, MemoryState]:
        """One eager step of the ordered memory (the per-slot reference implementation).

        Args:
            obs: ``[B, D]`` observations (raw; normalised inside).
            state: from :meth:`initial_state` or the previous step.
            sketch_emb: ``[B, m]`` task embedding overriding ``state.task_emb`` for this step only.
        Returns:
            ``(StepTensors, next MemoryState)``; rows whose ``state.first`` is True take the
            hard-coded first step (expand from the top, pi_end = 0).
        """
        self._check_obs(obs, 2)
        obs = obs.to(self.encoder.weight.dtype)
        n = self.config.n_slots
        e = state.task_emb if sketch_emb is None else sketch_emb
        x = self.encode_obs(obs)
        u = torch.cat([x, e], dim=-1)
        m_prev = [state.memory[:, i] for i in range(n)]
        first = state.first.unsqueeze(-1)

        cand = self._bottom_up(x, u, m_prev, first)  # skipped on the first step: C := M^0

        # scores and stick-breaking (first step: expand from the top, pi_end = 0)
        logits = torch.cat([self.score(u, m_prev[i], cand[i]) for i in range(n)], dim=-1)
        pi_hat, pi_end = stick_breaking(logits)
        top = torch.zeros_like(pi_hat)
        top[:, -1] = 1.0
        pi_hat = torch.where(first, top, pi_hat)
        pi_end = torch.where(state.first, torch.zeros_like(pi_end), pi_end)
        pi, rcp, cp = expansion_sums(pi_hat)

        m_hat = self._top_down(x, u, cand, rcp)
        new_slots = self._new_slots(m_prev, cand, m_hat, pi, rcp, cp)
        memory = torch.stack(new_slots, dim=1)
        action_out = self.denormalize_action(self.head(torch.cat([new_slots[0], e, x], dim=-1)))
        out = StepTensors(action_out=action_out, p_hat=to_p_hat(pi_hat, pi_end), pi=pi, pi_end=pi_end)
        new_state = MemoryState(memory=memory, first=torch.zeros_like(state.first), task_emb=state.task_emb)
        return out, new_state

    def _bottom_up(self, x: Tensor, u: Tensor, m_prev: list[Tensor], first: Tensor) -> list[Tensor]:
        """``C_1 .. C_n`` from ``C_0 = x`` (rows on their first step keep ``C := M^0``)."""
        if self.config.no_bottom_up:
            return list(m_prev)
        cand, below = [], x
        for i, cell in enumerate(self.com_cells):
            v = torch.zeros_like(below) if self.config.no_bottom_up_recurrence else below
            below = cell(v, m_prev[i], u)
            cand.append(torch.where(first, m_prev[i], below))
        return cand

    def _top_down(self, x: Tensor, u: Tensor, cand: list[Tensor], rcp: Tensor) -> list[Tensor]:
        """``M_hat_1 .. M_hat_n`` from ``M_hat_n = 0`` downwards (all zero for ``no_top_down``)."""
        n = self.config.n_slots
        m_hat = [torch.zeros_like(x) for _ in range(n)]
        if not self.config.no_top_down:
            for i in range(n - 1, 0, -1):
                parent = rcp[:, i : i + 1] * cand[i] + (1 - rcp[:, i : i + 1]) * m_hat[i]
                m_hat[i - 1] = self.decom_cells[i - 1](parent, u)
        return m_hat

    def _new_slots(
        self, m_prev: list[Tensor], cand: list[Tensor], m_hat: list[Tensor], pi: Tensor, rcp: Tensor,
        cp: Tensor,
    ) -> list[Tensor]:
        """``M^t`` slot by slot, by the configured ``memory_update`` rule (module docstring, step 5)."""
        new_slots = []
        for i in range(self.config.n_slots):
            r, c = rcp[:, i : i + 1], cp[:, i : i + 1]
            if self.config.memory_update == "paper":
                new_slots.append(m_prev[i] * (1 - c) + cand[i] * pi[:, i : i + 1] + m_hat[i] * (1 - r))
            else:
                new_slots.append(r * cand[i] + (1 - r) * m_hat[i])
        return new_slots

    def _sequence(
        self, obs: Tensor, mask: Tensor, sketch: Tensor | None, bptt: int, impl: str, bf16: bool
    ) -> SequenceOutput:
        """:meth:`PolicyInputs.forward_sequence` after its obs check: the fused path or the step loop."""
        obs = obs.to(self.encoder.weight.dtype)
        lengths = self._check_sequence(obs, mask, bptt)
        if impl == "fused":
            return fused_forward_sequence(self, obs, mask, lengths, sketch, bptt, bf16=bf16)
        if impl != "reference":
            raise ModelInputError(f"impl must be 'fused' or 'reference', got {impl!r}")
        if bf16:
            raise ModelInputError("bf16=True is only implemented by impl='fused'")
        batch, steps = mask.shape
        state = self.initial_state(batch, sketch)
        outs: list[StepTensors] = []
        for t in range(steps):
            out, state = self.step(obs[:, t], state)
            outs.append(out)
            if (t + 1) % bptt == 0:
                state = state.detach()
        keep = mask.unsqueeze(-1)
        if not outs:
            n, a = self.config.n_slots, self.config.action_dim
            empty = obs.new_zeros(batch, 0, 1)
            return SequenceOutput(
                empty.expand(batch, 0, a), empty.expand(batch, 0, n + 1), empty.expand(batch, 0, n), mask
            )
        return SequenceOutput(
            action_out=torch.where(keep, torch.stack([o.action_out for o in outs], dim=1), 0.0),
            p_hat=torch.where(keep, torch.stack([o.p_hat for o in outs], dim=1), 0.0),
            pi=torch.where(keep, torch.stack([o.pi for o in outs], dim=1), 0.0),
            mask=mask,
        )


def gaussian_log_prob(actions: Tensor, mean: Tensor, variance: float) -> Tensor:
    """log N(a; mu, variance * I) summed over the last dim (Dial head, docs/dial.md §4.3)."""
    dim = actions.shape[-1]
    return -((actions - mean) ** 2).sum(-1) / (2 * variance) - 0.5 * dim * float(np.log(2 * np.pi * variance))


__all__ = [
    "MemoryState",
    "OMPNPolicy",
    "SequenceOutput",
    "StepTensors",
    "expansion_sums",
    "gaussian_log_prob",
    "stick_breaking",
    "to_p_hat",
]
