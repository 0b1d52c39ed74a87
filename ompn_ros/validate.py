"""The one observation validator and the one sketch validator of the package (ROS-free).

Every place that accepts an observation (``StreamingSegmenter``, hence ``ompn_node`` and the offline
replay) calls :func:`validate_observation`; every place that accepts a sketch (the segmenter, the
marker parser :func:`parse_sketch_text`, the Dial sim) calls :func:`validate_sketch`.  Both raise
errors whose one-line message names what is at fault.

A sketch is the task's sequence of subtask ids (Lu et al., ICLR 2021, Sec. 4.1: the task sketch
conditions the policy); ids lie in ``0..vocab-1`` (``DomainLayout.sketch_vocab``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ompn_ros.errors import OMPNError

INT32_MAX = 2**31 - 1


class SketchError(OMPNError, ValueError):
    """A sketch is malformed or does not fit the vocabulary; the message says why."""


class InvalidInput(OMPNError, ValueError):
    """An input was rejected without stepping the model. ``reason`` is the counter key.

    Each kind of rejection is a subclass that names its key as a class keyword:
    ``class EmptyObservation(InvalidInput, reason="empty")``.
    """

    reason = "invalid"

    def __init_subclass__(cls, *, reason: str, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.reason = reason


class EmptyObservation(InvalidInput, reason="empty"):
    """The observation has no values."""


class WrongObservationLength(InvalidInput, reason="wrong_length"):
    """The observation does not have the model's ``obs_dim`` values."""


class NonFiniteObservation(InvalidInput, reason="non_finite"):
    """The observation is not numeric or holds a NaN/Inf value."""


class OutOfOrderStamp(InvalidInput, reason="out_of_order_stamp"):
    """The stamp is not later than the episode's last accepted stamp."""


class MissingSketch(InvalidInput, reason="no_sketch"):
    """The model needs a sketch and no episode was started with one."""


class EpisodeClosed(InvalidInput, reason="episode_closed"):
    """The observation arrived after the episode was ended and before the next one started."""


class MalformedMessage(InvalidInput, reason="malformed"):
    """The transport delivered bytes that do not decode as the expected message (raised by callers)."""


class BadStamp(InvalidInput, reason="bad_stamp"):
    """The stamp is not a valid ``builtin_interfaces/Time`` (raised by callers)."""


class FutureStamp(InvalidInput, reason="future_stamp"):
    """The stamp lies further ahead of the receiver's clock than allowed (raised by callers)."""


class BadSketch(InvalidInput, reason="bad_sketch"):
    """An episode start or sketch message carried a sketch the model cannot use (counted by callers)."""


REJECT_REASONS = tuple(kind.reason for kind in InvalidInput.__subclasses__())
"""Every rejection counter key, in the order the kinds are declared above."""


def validate_sketch(
    sketch: Sequence[int] | np.ndarray,
    vocab: int | None = None,
    *,
    length: int | None = None,
    no_immediate_repeat: bool = False,
) -> np.ndarray:
    """Return ``sketch`` as a non-empty 1-D int64 array or raise :class:`SketchError`.

    Rules: integer ids only (bools and floats are refused), ids in ``0..vocab-1`` when ``vocab`` is
    given (else ``0..2**31-1``), exactly ``length`` ids when given, and with ``no_immediate_repeat``
    no id twice in a row (the Dial task, ``docs/dial.md`` §2.5).  O(len(sketch)).
    """
    try:
        arr = np.asarray(sketch)
    except (TypeError, ValueError, OverflowError) as exc:
        raise SketchError(f"sketch is not a list of integer ids: {exc}") from None
    if arr.dtype == object and arr.ndim == 1 and all(isinstance(v, int) and not isinstance(v, bool)
                                                     for v in arr.tolist()):
        values = arr.tolist()
        if any(v < 0 or v > INT32_MAX for v in values):
            raise SketchError(f"sketch ids {values} are outside 0..{INT32_MAX}")
        arr = np.asarray(values, dtype=np.int64)
    if arr.ndim != 1 or arr.size == 0:
        raise SketchError(f"sketch must be a non-empty 1-D list of ids, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer) or arr.dtype == np.bool_:
        raise SketchError(f"sketch ids must be integers, got {arr.dtype}: {arr.tolist()}")
    top = INT32_MAX if vocab is None else int(vocab) - 1
    if int(arr.min()) < 0 or int(arr.max()) > top:
        raise SketchError(f"sketch ids {arr.tolist()} are outside the vocabulary 0..{top}")
    if length is not None and arr.size != length:
        raise SketchError(f"sketch must have {length} ids, got {arr.size}: {arr.tolist()}")
    if no_immediate_repeat and bool(np.any(arr[1:] == arr[:-1])):
        raise SketchError(f"sketch must not repeat an id immediately, got {arr.tolist()}")
    return arr.astype(np.int64)


def parse_sketch_text(text: str, vocab: int | None = None) -> np.ndarray:
    """Comma-separated ids (an episode marker's ``sketch`` value) -> int64 array; '' -> empty array.

    Raises :class:`SketchError` (a ``ValueError``) on anything else, huge numbers included.  O(len(text)).
    """
    text = text.strip()
    if not text:
        return np.zeros(0, dtype=np.int64)
    parts = text.split(",")
    if len(parts) > 10_000 or any(len(p.strip()) > 10 for p in parts):
        raise SketchError(f"sketch value {text[:40]!r} is not a list of small integer ids")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise SketchError(f"sketch value {text[:40]!r} is not a comma-separated list of integers") from None
    return validate_sketch(values, vocab)


def all_finite(arr: np.ndarray) -> bool:
    """True when no value of ``arr`` is NaN or infinite (numpy; the segmenter passes a compiled one)."""
    return bool(np.isfinite(arr).all())


def validate_observation(
    obs: Any, obs_dim: int, finite: Callable[[np.ndarray], bool] = all_finite
) -> np.ndarray:
    """Return ``obs`` as contiguous float32 ``[obs_dim]`` or raise an :class:`InvalidInput` subclass.

    Checks, in order: numeric, non-empty, length ``obs_dim``, all finite (``finite``).  A flat contiguous
    float32 array (the node's parsed messages) skips every conversion: this runs once per step.
    O(obs_dim).
    """
    if type(obs) is np.ndarray and obs.dtype == np.float32 and obs.ndim == 1 and obs.flags.c_contiguous:
        arr = obs
    else:
        try:
            arr = np.asarray(obs, dtype=np.float32)
        except (TypeError, ValueError, OverflowError) as exc:
            raise NonFiniteObservation(f"observation is not numeric: {exc}") from exc
        arr = np.ascontiguousarray(arr.reshape(-1))
    if arr.size == 0:
        raise EmptyObservation("observation is empty")
    if arr.size != obs_dim:
        raise WrongObservationLength(
            f"observation has {arr.size} values, the model expects obs_dim={obs_dim}"
        )
    if not finite(arr):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise NonFiniteObservation(f"observation has a NaN/Inf value (first at index {bad})")
    return arr
