"""LSTM behaviour-cloning baseline with the OMPN policy interface (docs/craft.md §3.11, paper Fig. 6).

Architecture (the authors' ``lstm`` bot, adapted to our interface):

* ``x = LN(W_in((s - mean) / scale) + b_in)`` (LayerNorm with affine);
* an ``nn.LSTM`` with ``num_layers = n_slots`` and hidden size ``slot_size``; the initial
  ``(h, c)`` of every layer is a linear function of the task embedding e (the authors' "env
  encoder" of size 2·layers·H); e = sum of learned subtask embeddings (as in OMPN) or 0;
* head on ``[lstm_out; e; x]``.

'done' is expressed as pi_end so :func:`ompn_ros.model.loss.bc_loss` applies unchanged:

* discrete: a 6-way (``action_dim + 1``) softmax whose last class is done.  ``action_out`` holds the
  first ``action_dim`` logits and ``pi_end = softmax_{A+1}[A]``; since
  ``softmax_A(l)_a (1 - pi_end) = softmax_{A+1}(l)_a`` the OMPN loss is exactly the 6-way cross entropy.
* continuous: ``action_out`` = Gaussian mean, ``pi_end = sigmoid(done head)`` (a Bernoulli done).

**The LSTM has no hierarchy.**  Its ``p_hat`` is ``[pi_end, 1 - pi_end, 0, ..., 0]`` (all the
non-done mass on the top slot) and ``pi`` is one-hot on the top slot; detectors run on it produce
no meaningful boundaries.  They exist only so the trainer, the evaluation and the streaming
consumers work for both architectures.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ConfigError, ModelInputError, StreamingInputError
from ompn_ros.model.policy import PolicyInputs, SequenceOutput
from ompn_ros.model.step_output import StepOutput, checked_observation, sketch_tensor

LSTMState = tuple[Tensor, Tensor]


class LSTMPolicy(PolicyInputs, nn.Module):
    """The LSTM baseline; same public methods as :class:`~ompn_ros.model.policy.OMPNPolicy`
    for training (``forward_sequence``, ``set_obs_normalization``, ``config``)."""

    obs_mean: Tensor
    obs_scale: Tensor

    def __init__(self, config: OMPNConfig) -> None:
        super().__init__()
        if config.arch != "lstm":
            raise ConfigError(f"LSTMPolicy needs OMPNConfig.arch='lstm', got {config.arch!r}")
        self.config = config
        n, m = config.n_slots, config.slot_size
        self.encoder = nn.Linear(config.obs_dim, m)
        self.input_norm = nn.LayerNorm(m)
        self.lstm = nn.LSTM(m, m, num_layers=n, batch_first=True)
        self.init_state = nn.Linear(m, 2 * n * m)  # the authors' env encoder -> (h0, c0)
        discrete = config.action_type == "discrete"
        self.head = nn.Linear(3 * m, config.action_dim + 1 if discrete else config.action_dim)
        self.done_head: nn.Linear | None = None if discrete else nn.Linear(3 * m, 1)
        self.register_inputs()

    # --- inputs (same contract as OMPNPolicy) ------------------------------------------------------
    def encode_obs(self, obs: Tensor) -> Tensor:
        """x = LN(W_in((s - mean) / scale) + b_in)."""
        return self.input_norm(self.encoder((obs - self.obs_mean) / self.obs_scale))

    # --- recurrence --------------------------------------------------------------------------------
    def initial_state(self, e: Tensor) -> LSTMState:
        """``(h0, c0)``, each ``[n_layers, B, m]``, from the task embedding ``e [B, m]``."""
        n, m = self.config.n_slots, self.config.slot_size
        hc = self.init_state(e).view(e.shape[0], 2, n, m)
        return hc[:, 0].transpose(0, 1).contiguous(), hc[:, 1].transpose(0, 1).contiguous()

    def heads(self, out: Tensor, e: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(action_out [..., A], pi_end [...])`` from the LSTM output, e and x (see module docstring)."""
        feats = torch.cat([out, e.expand_as(out) if e.dim() == out.dim() else e, x], dim=-1)
        logits = self.head(feats)
        if self.done_head is None:
            return logits[..., :-1], torch.softmax(logits, dim=-1)[..., -1]
        return self.denormalize_action(logits), torch.sigmoid(self.done_head(feats)).squeeze(-1)

    def hierarchy_outputs(self, pi_end: Tensor) -> tuple[Tensor, Tensor]:
        """``(p_hat [..., n+1], pi [..., n])``: ``[pi_end, 1 - pi_end, 0, ...]`` and one-hot(top slot)."""
        n = self.config.n_slots
        p_hat = torch.cat(
            [pi_end.unsqueeze(-1), (1 - pi_end).unsqueeze(-1), pi_end.new_zeros(*pi_end.shape, n - 1)], dim=-1
        )
        pi = pi_end.new_zeros(*pi_end.shape, n)
        pi[..., -1] = 1.0
        return p_hat, pi

    def _sequence(
        self, obs: Tensor, mask: Tensor, sketch: Tensor | None, bptt: int, impl: str, bf16: bool
    ) -> SequenceOutput:
        """:meth:`PolicyInputs.forward_sequence` after its obs check; ``(h, c)`` is detached every
        ``bptt`` steps, ``impl`` only checked and ``bf16`` ignored (both values run ``nn.LSTM``)."""
        del bf16
        if impl not in ("fused", "reference"):
            raise ModelInputError(f"impl must be 'fused' or 'reference', got {impl!r}")
        self._check_sequence(obs, mask, bptt)  # the prefix layout: padding follows valid steps, so causality
        obs = obs.to(self.encoder.weight.dtype)  # keeps padded steps from affecting valid ones
        batch, steps = mask.shape
        e = self.embed_sketch(sketch, batch)
        x = self.encode_obs(obs)
        state = self.initial_state(e)
        chunks = []
        for start in range(0, steps, bptt):
            out, state = self.lstm(x[:, start : start + bptt], state)
            chunks.append(out)
            state = (state[0].detach(), state[1].detach())
        lstm_out = torch.cat(chunks, dim=1) if chunks else x.new_zeros(batch, 0, self.config.slot_size)
        e_seq = e.unsqueeze(1).expand(batch, steps, e.shape[-1])
        action_out, pi_end = self.heads(lstm_out, e_seq, x)
        p_hat, pi = self.hierarchy_outputs(pi_end)
        keep = mask.unsqueeze(-1)
        return SequenceOutput(
            action_out=torch.where(keep, action_out, 0.0),
            p_hat=torch.where(keep, p_hat, 0.0),
            pi=torch.where(keep, pi, 0.0),
            mask=mask,
        )


class LSTMStreamingPolicy:
    """Stateful batch-1 stepping of an :class:`LSTMPolicy` with numpy in and out.

    Same interface as :class:`~ompn_ros.model.streaming.StreamingPolicy` (``reset(sketch)``,
    ``step(obs) -> StepOutput``, ``config``); torch under ``inference_mode``, its one ``backend``
    (``'torch'``).
    """

    def __init__(self, policy: LSTMPolicy, backend: str = "torch") -> None:
        if backend == "numpy":
            raise StreamingInputError("the LSTM stepper has no backend 'numpy': it steps with torch, "
                                      "backend='torch'")
        if backend != "torch":
            raise StreamingInputError(f"the LSTM stepper's backend is 'torch', got {backend!r}")
        self.policy = policy
        self.config = policy.config
        self.backend = backend
        self._ready = False
        self._state: LSTMState | None = None
        self._e: Tensor | None = None
        if self.config.sketch_mode == "none":
            self.reset()

    def reset(self, sketch: np.ndarray | None = None) -> None:
        """Start a new episode: ``(h0, c0)`` from the task embedding."""
        with torch.inference_mode():
            self._e = self.policy.embed_sketch(sketch_tensor(sketch), 1)
            self._state = self.policy.initial_state(self._e)
        self._ready = True

    def step(self, obs: np.ndarray) -> StepOutput:
        """Advance the LSTM by one observation; ``action`` = argmax over env actions (done excluded)."""
        arr = checked_observation(obs, self.config.obs_dim, self._ready)
        assert self._e is not None and self._state is not None
        with torch.inference_mode():
            x = self.policy.encode_obs(torch.from_numpy(arr).view(1, 1, -1))
            out, self._state = self.policy.lstm(x, self._state)
            action_out, pi_end_t = self.policy.heads(out[:, 0], self._e, x[:, 0])
            p_hat_t, pi_t = self.policy.hierarchy_outputs(pi_end_t)
        pi_end = float(pi_end_t[0])
        logits = action_out[0].numpy().astype(np.float32)
        action: np.ndarray | int = int(np.argmax(logits)) if self.config.action_type == "discrete" else logits
        pi = pi_t[0].numpy().astype(np.float32)
        return StepOutput(
            action=action,
            pi=pi,
            pi_end=pi_end,
            p_hat=p_hat_t[0].numpy().astype(np.float32),
            expected_position=float(np.dot(np.arange(1, pi.size + 1), pi)),
            done_prob=pi_end,
            action_logits=logits if self.config.action_type == "discrete" else None,
        )


__all__ = ["LSTMPolicy", "LSTMStreamingPolicy"]
