"""What every batch-1 stepper returns (:class:`StepOutput`) and the input checks they share.

Used by the OMPN stepper (``streaming.py``), the LSTM baseline (``lstm.py``) and ensembles
(``ensemble.py``), so that none of them imports another.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ompn_ros.model.errors import StreamingInputError
from ompn_ros.validate import InvalidInput, validate_observation


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
        action_logits: discrete: the env-action logits ``[A]`` (float32; their softmax is the
            action distribution given "not done"); continuous: None.
    """

    action: np.ndarray | int
    pi: np.ndarray
    pi_end: float
    p_hat: np.ndarray
    expected_position: float
    done_prob: float
    action_logits: np.ndarray | None = None


def checked_observation(obs: np.ndarray, obs_dim: int, ready: bool) -> np.ndarray:
    """``obs`` as a flat float32 vector, or a StreamingInputError naming what is wrong with it."""
    if not ready:
        raise StreamingInputError("this model has sketch_mode='sum': call reset(sketch) before step()")
    try:
        return validate_observation(obs, obs_dim)
    except InvalidInput as exc:
        raise StreamingInputError(str(exc)) from None


def sketch_tensor(sketch: np.ndarray | None) -> torch.Tensor | None:
    """A streaming sketch ``[K]`` as the ``[1, K]`` int64 tensor the policies take (None stays None)."""
    if sketch is None:
        return None
    arr = np.asarray(sketch)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
        raise StreamingInputError(f"sketch must be a 1-D integer array [K], got {arr.shape} {arr.dtype}")
    return torch.as_tensor(arr.astype(np.int64)).unsqueeze(0)


__all__ = ["StepOutput", "checked_observation", "sketch_tensor"]
