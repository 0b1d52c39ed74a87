"""StreamingPolicy: stateful batch-1 OMPN stepping with numpy in and out (live node, replay).

Three backends share the weights of one :class:`OMPNPolicy`:

* ``'jit'`` (default): the numpy backend's weights and arithmetic compiled into one call with numba
  (:class:`~ompn_ros.model._jit_stream.JitStepper`); compiled (or loaded from numba's cache) at
  construction, so the first step is as fast as the others.
* ``'numpy'``: a float32 numpy re-implementation of :meth:`OMPNPolicy.step` with the
  weights copied and pre-sliced at construction (:class:`~ompn_ros.model._fast_stream.NumpyStepper`).
  Everything that depends only on the episode (the task embedding's contribution to every layer) is
  computed once in :meth:`reset`, the observation normalisation is folded into the encoder, all
  projections of x are one matrix-vector product, and sparse observations are encoded by a gather.
* ``'torch'``: the eager :meth:`OMPNPolicy.step` under ``torch.inference_mode`` (the reference).
  Its ``device`` argument (default CPU) runs the module and every step's tensors there (a copy of
  the module moved to that device); the two compiled backends run on the CPU only.

All three agree to float32 rounding (tested to 1e-5).  Weights are copied at construction: later
changes to the module are not seen (build a new StreamingPolicy after training).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ompn_ros.model._fast_stream import NumpyStepper
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import StreamingInputError
from ompn_ros.model.policy import MemoryState, OMPNPolicy
from ompn_ros.model.step_output import StepOutput, checked_observation, sketch_tensor

Backend = Literal["jit", "numpy", "torch"]
BACKENDS: tuple[Backend, ...] = ("jit", "numpy", "torch")


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


class StreamingPolicy:
    """Stateful, batch-1, no-autograd OMPN stepping; see the module docstring."""

    def __init__(
        self, policy: OMPNPolicy, backend: Backend = "jit", device: torch.device | str = "cpu"
    ) -> None:
        if backend not in BACKENDS:
            raise StreamingInputError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.device = torch.device(device)
        if self.device.type != "cpu":
            if backend != "torch":
                raise StreamingInputError(f"backend {backend!r} runs on the CPU only; use backend='torch' "
                                          f"for device {self.device}")
            policy = copy.deepcopy(policy).to(self.device)  # the caller's module stays where it is
        self.policy = policy  # no dropout or batch norm: train/eval mode does not matter
        self.config: OMPNConfig = policy.config
        self.backend = backend
        self._w: NumpyStepper | None = None
        if backend == "jit":
            # numba is imported only for this backend (it adds ~0.6 s to the import of torch)
            from ompn_ros.model._jit_stream import JitStepper

            jit = JitStepper(policy)
            jit.warm_up()
            self._w = jit
        elif backend == "numpy":
            self._w = NumpyStepper(policy)
        self._ready = False
        self._state: MemoryState | None = None
        if self.config.sketch_mode == "none":
            self.reset()

    @classmethod
    def from_checkpoint(
        cls, path: str | Path, backend: Backend = "jit", device: torch.device | str = "cpu"
    ) -> StreamingPolicy:
        """The stepper of an OMPN checkpoint (``arch='ompn'``); for any architecture or an ensemble
        directory use :func:`ompn_ros.model.load.stepper_from_checkpoint`."""
        policy, _ = load_checkpoint(path)
        if not isinstance(policy, OMPNPolicy):
            raise StreamingInputError(
                f"{path}: arch={policy.config.arch!r} is not an OMPN checkpoint; use "
                "ompn_ros.model.load.stepper_from_checkpoint for any architecture"
            )
        return cls(policy, backend=backend, device=device)

    def reset(self, sketch: np.ndarray | None = None) -> None:
        """Start a new episode (initial memory M^0; the next step is the hard-coded first step)."""
        sketch_t = sketch_tensor(sketch)
        if sketch_t is not None:
            sketch_t = sketch_t.to(self.device)
        with torch.inference_mode():
            state = self.policy.initial_state(1, sketch_t)
        self._state = state
        if self._w is not None:
            self._w.reset(_np(state.task_emb[0]), _np(state.memory[0]))
        self._ready = True

    @property
    def _memory(self) -> np.ndarray:
        """Numpy backend: the current memory ``[n, m]`` float32 (slot 1 first); read-only use."""
        assert self._w is not None
        return self._w.memory


    def step(self, obs: np.ndarray) -> StepOutput:
        """Advance the memory by one observation and return the action and expansion distribution."""
        return self.step_trusted(checked_observation(obs, self.config.obs_dim, self._ready))

    def step_trusted(self, arr: np.ndarray) -> StepOutput:
        """:meth:`step` on an observation the caller has already checked: float32, contiguous
        ``[obs_dim]``, finite, after a :meth:`reset` (``StreamingSegmenter.validate`` does that)."""
        if self._w is None:
            return self._step_torch(arr)
        return self._step_numpy(arr)

    def _finish(
        self, action_out: np.ndarray, pi_hat: Sequence[float], pi_end: float, pi: Sequence[float]
    ) -> StepOutput:
        pi_arr = np.array(pi, dtype=np.float32)
        p_hat = np.array([pi_end, *pi_hat[::-1]], dtype=np.float32)
        logits = None
        if self.config.action_type == "discrete":
            action: np.ndarray | int = int(action_out.argmax())
            logits = np.array(action_out, dtype=np.float32)  # a copy: the numpy backend reuses its buffer
        else:
            action = action_out.astype(np.float32)
        return StepOutput(
            action=action,
            pi=pi_arr,
            pi_end=float(pi_end),
            p_hat=p_hat,
            expected_position=float(sum(k * p for k, p in enumerate(pi, start=1))),
            done_prob=float(pi_end),
            action_logits=logits,
        )

    def _step_torch(self, arr: np.ndarray) -> StepOutput:
        assert self._state is not None
        with torch.inference_mode():
            obs = torch.from_numpy(arr).unsqueeze(0).to(self.device)
            out, self._state = self.policy.step(obs, self._state)
        pi_hat = out.p_hat[0, 1:].flip(0).tolist()
        return self._finish(out.action_out[0].cpu().numpy(), pi_hat, float(out.pi_end[0]), out.pi[0].tolist())

    def _step_numpy(self, s: np.ndarray) -> StepOutput:
        assert self._w is not None
        action_out, pi_hat, pi_end, pi = self._w.step(s)
        return self._finish(action_out, pi_hat, pi_end, pi)


__all__ = [
    "BACKENDS",
    "Backend",
    "StepOutput",
    "StreamingPolicy",
    "checked_observation",
    "sketch_tensor",
]
