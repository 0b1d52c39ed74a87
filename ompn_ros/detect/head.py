"""A learned causal boundary detector: the boundary head (docs/design.md#boundary-head).

The threshold and duration detectors read one number per step, the expansion score.  The boundary
head reads the model's whole output of the last ``window`` steps: ``p_hat`` (the paper's expansion
distribution, Lu et al., ICLR 2021, §3.3) beside the action output (the action probabilities for
discrete actions, the action mean for continuous ones), standardised.  A small network (two hidden
ReLU layers) gives, for each lag ``j = 0 … max_lag``, the probability that step ``t - j`` ended a
subtask.  ``ompn_train`` fits it on the labels of the training episodes
(:mod:`ompn_ros.train.boundary_head`); nothing of the OMPN changes.

Decoding (:class:`HeadDecoder`), with the :class:`~ompn_ros.detect.online.DetectorConfig` of mode
'head' (``high`` = θ, ``lag`` = d, ``min_segment_length`` = gap):

* the row of step ``t`` is taken in when step ``t + 1`` arrives (or the episode is closed), as the
  duration decoder does, so an episode's 'done' observation, dropped by the episode end, never
  places a boundary;
* taking in the row of step ``t`` publishes step ``s = t - d`` (``s >= 1``, before the last step)
  when its probability at lag ``d`` is at least θ, it is at least ``gap`` steps after the previous
  boundary and, with the head's ``peak``, lag ``d - 1`` is not likelier (the boundary is not still
  coming); a boundary is thus published ``d + 1`` steps after its step;
* the episode end reads the last row at the smaller lags for its last ``d - 1`` steps, then closes
  the episode at its last step.

Cost per step: one pass of the network, ``window · F · h + h² + h · (max_lag + 1)`` multiply-adds
(``F`` outputs per step, ``h`` hidden units).  Memory: the window and the last few rows.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ompn_ros.atomic import atomic_write
from ompn_ros.detect.errors import BoundaryHeadError, DetectorConfigError
from ompn_ros.detect.online import HEAD_MODE, KEPT_STEPS, BoundaryEvent, DetectorConfig, EpisodeLog

HEAD_FILE = "boundary_head.safetensors"
"""The head's weights, next to ``detector.json`` (which holds its :meth:`BoundaryHead.meta`)."""
LAYERS = 3
MAX_WINDOW = 64
MAX_WIDTH = 4096


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return np.asarray(0.5 * (1.0 + np.tanh(0.5 * x)))


@dataclass(frozen=True, eq=False)
class BoundaryHead:
    """A trained head, checked on construction.

    Attributes:
        weights: ``LAYERS`` pairs ``(W [in, out], b [out])``; the first ``in`` is ``window · features``,
            the last ``out`` is ``max_lag + 1``.
        mean, std: the input standardisation ``[window · features]`` (``std > 0``).
        window: steps read (the current one and ``window - 1`` before it).
        features: outputs per step, ``n + 1 + A`` (``p_hat`` and the action output).
        peak: the decoding waits while lag ``d - 1`` is likelier than lag ``d``.
        episodes: how many episodes it was trained on.
        rule: the decoding chosen with it on validation episodes (mode 'head'; None: not chosen), kept
            also when another detector runs, so that ``detector_mode: head`` can be set to it.
    """

    weights: tuple[tuple[np.ndarray, np.ndarray], ...]
    mean: np.ndarray
    std: np.ndarray
    window: int
    features: int
    peak: bool = False
    episodes: int = 0
    rule: DetectorConfig | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.window <= MAX_WINDOW or not 1 <= self.features <= MAX_WIDTH:
            raise BoundaryHeadError(f"boundary head: window {self.window} or features {self.features} "
                                    "out of range")
        width = self.window * self.features
        if len(self.weights) != LAYERS:
            raise BoundaryHeadError(f"boundary head: {len(self.weights)} layers, expected {LAYERS}")
        for name, arr in (("mean", self.mean), ("std", self.std)):
            if arr.shape != (width,) or not np.all(np.isfinite(arr)):
                raise BoundaryHeadError(f"boundary head: '{name}' must be finite [{width}], got {arr.shape}")
        if not np.all(self.std > 0):
            raise BoundaryHeadError("boundary head: 'std' must be > 0")
        for i, (w, b) in enumerate(self.weights):
            if w.ndim != 2 or w.shape[0] != width or b.shape != (w.shape[1],):
                raise BoundaryHeadError(f"boundary head: layer {i} is {w.shape} + {b.shape}, its input is "
                                        f"{width}")
            if not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))):
                raise BoundaryHeadError(f"boundary head: layer {i} holds NaN or infinity")
            width = w.shape[1]
        if width < 2:
            raise BoundaryHeadError(f"boundary head: {width} outputs, expected max_lag + 1 >= 2")
        if self.rule is not None and (self.rule.mode != HEAD_MODE or self.rule.lag > width - 1):
            raise BoundaryHeadError(f"boundary head: its rule must be of mode '{HEAD_MODE}' with lag <= "
                                    f"{width - 1}, got {self.rule}")

    def __eq__(self, other: object) -> bool:  # by value, as stored
        if not isinstance(other, BoundaryHead) or self.meta() != other.meta():
            return False
        mine, theirs = self.tensors(), other.tensors()
        return all(np.array_equal(mine[k], theirs[k]) for k in mine)

    def __hash__(self) -> int:
        return hash((self.window, self.features, self.max_lag, self.episodes))

    @property
    def max_lag(self) -> int:
        """The longest lag the head gives a probability for."""
        return int(self.weights[-1][0].shape[1]) - 1

    def forward(self, z: np.ndarray) -> np.ndarray:
        """Probabilities ``[..., max_lag + 1]`` of windowed inputs ``[..., window · features]``."""
        h = (z - self.mean) / self.std
        for i, (w, b) in enumerate(self.weights):
            h = h @ w + b
            if i < LAYERS - 1:
                h = np.maximum(h, 0.0)
        return _sigmoid(h)

    def probabilities(self, outputs: np.ndarray) -> np.ndarray:
        """``[T, max_lag + 1]`` of one episode's outputs ``[T, features]``, row ``t`` from rows ``<= t``."""
        return self.forward(windowed(np.asarray(outputs, dtype=np.float64), self.window))

    def meta(self) -> dict[str, Any]:
        """What ``detector.json`` keeps of the head (the weights go to :data:`HEAD_FILE`)."""
        return {"file": HEAD_FILE, "window": self.window, "features": self.features,
                "hidden": [int(w.shape[1]) for w, _ in self.weights[:-1]], "max_lag": self.max_lag,
                "peak": bool(self.peak), "episodes": int(self.episodes),
                "rule": None if self.rule is None else self.rule.to_dict()}

    def tensors(self) -> dict[str, np.ndarray]:
        named = {"mean": self.mean, "std": self.std}
        for i, (w, b) in enumerate(self.weights):
            named[f"w{i}"], named[f"b{i}"] = w, b
        return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in named.items()}


def windowed(x: np.ndarray, window: int) -> np.ndarray:
    """``[T, window · F]``: rows ``t - window + 1 … t`` of ``x`` side by side (row 0 repeated before it)."""
    pad = np.concatenate([np.repeat(x[:1], window - 1, axis=0), x], axis=0)
    return np.concatenate([pad[i:i + len(x)] for i in range(window)], axis=1)


def head_outputs(p_hat: np.ndarray, action_out: np.ndarray, discrete: bool) -> np.ndarray:
    """One step's (or ``[T, …]`` steps') head input: ``p_hat`` beside the action probabilities (the
    softmax of the logits) for discrete actions, or the action mean for continuous ones."""
    act = np.asarray(action_out, dtype=np.float64)
    if discrete:
        act = np.exp(act - act.max(axis=-1, keepdims=True))
        act = act / act.sum(axis=-1, keepdims=True)
    return np.concatenate([np.asarray(p_hat, dtype=np.float64), act], axis=-1)


def step_outputs(step: Any) -> np.ndarray:
    """:func:`head_outputs` of one stepper ``StepOutput``: its action logits when it has them
    (discrete actions), else its action (the continuous mean)."""
    discrete = step.action_logits is not None
    return head_outputs(step.p_hat, step.action_logits if discrete else step.action, discrete)


def expected_shapes(meta: dict[str, Any]) -> dict[str, tuple[int, ...]]:
    """The tensor shapes a head of ``meta`` holds (checked against the file before loading)."""
    width = int(meta["window"]) * int(meta["features"])
    sizes = [width, *(int(h) for h in meta["hidden"]), int(meta["max_lag"]) + 1]
    shapes: dict[str, tuple[int, ...]] = {"mean": (width,), "std": (width,)}
    for i in range(len(sizes) - 1):
        shapes[f"w{i}"], shapes[f"b{i}"] = (sizes[i], sizes[i + 1]), (sizes[i + 1],)
    return shapes


def _check_meta(meta: Any, origin: str) -> dict[str, Any]:
    keys = {"file", "window", "features", "hidden", "max_lag", "peak", "episodes"}
    if not isinstance(meta, dict) or not keys <= set(meta) <= keys | {"rule"}:
        raise BoundaryHeadError(f"{origin}: 'boundary_head' must have the keys {sorted(keys)} (and 'rule')")
    ints = [meta["window"], meta["features"], meta["max_lag"], meta["episodes"], *meta["hidden"]]
    if not isinstance(meta["hidden"], list) or len(meta["hidden"]) != LAYERS - 1 or not all(
            isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_WIDTH for v in ints):
        raise BoundaryHeadError(f"{origin}: 'boundary_head' sizes must be {LAYERS - 1} hidden widths and "
                                f"integers in [0, {MAX_WIDTH}]")
    if meta["file"] != HEAD_FILE or not isinstance(meta["peak"], bool):
        raise BoundaryHeadError(f"{origin}: 'boundary_head' needs file '{HEAD_FILE}' and a boolean 'peak'")
    return meta


def load_head(directory: Path, meta: Any, origin: str) -> BoundaryHead:
    """The head of ``meta`` (``detector.json``'s ``boundary_head``) from ``directory/HEAD_FILE``: the
    file's header is checked against ``meta`` before any tensor is read."""
    from safetensors import SafetensorError, safe_open

    meta = _check_meta(meta, origin)
    path = directory / HEAD_FILE
    expected = expected_shapes(meta)
    try:
        with safe_open(str(path), framework="np") as handle:
            header = {k: (tuple(handle.get_slice(k).get_shape()), handle.get_slice(k).get_dtype())
                      for k in handle.keys()}
            if header != {k: (v, "F32") for k, v in expected.items()}:
                raise BoundaryHeadError(f"{path}: tensors {sorted(header.items())} do not match {origin}'s "
                                        f"boundary_head (expected float32 {sorted(expected.items())})")
            got = {k: handle.get_tensor(k).astype(np.float64) for k in expected}
    except (SafetensorError, OSError) as exc:
        raise BoundaryHeadError(f"{path}: not a readable safetensors file: {exc}") from exc
    weights = tuple((got[f"w{i}"], got[f"b{i}"]) for i in range(LAYERS))
    try:
        rule = None if meta.get("rule") is None else DetectorConfig.from_dict(dict(meta["rule"]))
    except (DetectorConfigError, TypeError, ValueError) as exc:
        raise BoundaryHeadError(f"{origin}: 'boundary_head.rule': {exc}") from exc
    return BoundaryHead(weights, got["mean"], got["std"], meta["window"], meta["features"], meta["peak"],
                        meta["episodes"], rule)


def write_head(directory: Path, head: BoundaryHead) -> Path:
    """Write ``directory/HEAD_FILE`` whole or not at all (:func:`ompn_ros.atomic.atomic_write`);
    ``detector.json``, written after it, names it."""
    from safetensors.numpy import save

    path = directory / HEAD_FILE
    data = save(head.tensors(), metadata={"boundary_head": json.dumps(head.meta())})
    atomic_write(path, lambda handle: handle.write(data))
    return path


@dataclass(eq=False)
class HeadDecoder(EpisodeLog):
    """The decoding of the module docstring over rows of probabilities: :meth:`take` one row per step."""

    config: DetectorConfig
    max_lag: int
    peak: bool = False
    _rows: deque[tuple[int, np.ndarray]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.check(self.config)
        self.reset()

    @property
    def lag(self) -> int:
        return int(self.config.lag)

    def check(self, config: DetectorConfig) -> None:
        if config.mode != HEAD_MODE:
            raise BoundaryHeadError(f"the boundary head decodes mode '{HEAD_MODE}' with lag 0 … "
                                    f"{self.max_lag}, got mode '{config.mode}'")
        if not 0 <= config.lag <= self.max_lag:
            raise BoundaryHeadError(f"detector_lag {config.lag} is beyond this boundary head's lags "
                                    f"(lag 0 … {self.max_lag})")

    def configure(self, config: DetectorConfig) -> None:
        """Run ``config`` (same lag) from the next step on."""
        self.check(config)
        if config.lag != self.config.lag:
            raise BoundaryHeadError(f"the lag changes from the next episode (a new decoder), got "
                                    f"{config.lag}")
        self.config = config

    def reset(self) -> None:
        self._start(keep=KEPT_STEPS + self.max_lag + 2)
        self._rows = deque(maxlen=KEPT_STEPS + 2)

    def take(self, row: np.ndarray, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the next step's probabilities ``[max_lag + 1]``; the boundary published now, if any."""
        record = self._next(score, level, stamp_ns, self.config.force_first_step_low)
        event = self._take_in(self._rows[-1], self._step) if self._rows else None
        self._recent.append((self._step, record))
        self._rows.append((self._step, row))
        return event

    def _fires(self, row: np.ndarray, s: int, j: int) -> bool:
        if s < 1 or (self._n_boundaries and s - self._last_boundary < self.config.min_segment_length):
            return False
        if row[j] < self.config.high:
            return False
        return not (self.peak and j > 0 and row[j - 1] > row[j])

    def _take_in(self, step_row: tuple[int, np.ndarray], now: int) -> BoundaryEvent | None:
        t, row = step_row
        s = t - self.lag
        return self._emit(s, now, self._record(s)) if self._fires(row, s, self.lag) else None

    def close(self, last_step: int | None = None) -> list[BoundaryEvent]:
        """Close the episode at ``last_step`` (default: the last step seen): the boundaries its last
        row still places, then the final event: the last segment's boundary, or the episode end (no
        subtask) when a boundary already ends there or fewer than ``min_segment_length`` steps before
        (docs/design.md#episode-end)."""
        end = self._close_at(last_step)
        if end is None:
            return []
        events: list[BoundaryEvent] = []
        rows = dict(self._rows)
        if self._step <= end and end in rows and self.lag > 0:  # lag 0: the final boundary is that step
            taken = self._take_in((end, rows[end]), self._step)
            events += [taken] if taken is not None else []
        for s in range(max(1, end + 1 - self.lag), end):
            if end in rows and self._fires(rows[end], s, end - s):
                events.append(self._emit(s, self._step, self._record(s)))
        events.append(self._closing(end, min_length=self.config.min_segment_length))
        return events


class HeadInput:
    """The head over a stream: :meth:`feed` each step's outputs, then :meth:`row` gives that step's
    probabilities (the window starts filled with the episode's first step)."""

    def __init__(self, head: BoundaryHead) -> None:
        self.head = head
        self._window = np.zeros((head.window, head.features))
        self.reset()

    def reset(self) -> None:
        self._fed: np.ndarray | None = None
        self._steps = 0

    def feed(self, outputs: np.ndarray) -> None:
        """The step's model outputs (:func:`head_outputs`), read by the next :meth:`row`."""
        if outputs.shape != (self.head.features,):
            raise BoundaryHeadError(f"the boundary head reads {self.head.features} outputs per step, got "
                                    f"{outputs.shape}")
        self._fed = outputs

    def row(self) -> np.ndarray:
        """The probabilities ``[max_lag + 1]`` of the step fed last."""
        if self._fed is None:
            raise BoundaryHeadError("a head detector's update came without the step's outputs: "
                                    "feed() them first")
        if self._steps == 0:
            self._window[:] = self._fed
        else:
            self._window[:-1] = self._window[1:]
            self._window[-1] = self._fed
        self._fed, self._steps = None, self._steps + 1
        return self.head.forward(self._window.ravel())


class FedByHead:
    """A streaming detector over the head's rows: :meth:`feed` the step's outputs, then :meth:`update`
    takes the step's row (the class it is mixed into decodes rows with ``take``)."""

    head: BoundaryHead
    input: HeadInput
    if TYPE_CHECKING:  # the decoder's, found after this class in the method order
        def take(self, row: np.ndarray, score: float, level: int = 0,
                 stamp_ns: int = 0) -> BoundaryEvent | None: ...

    def _attach(self, head: BoundaryHead) -> None:
        self.head, self.input = head, HeadInput(head)

    def reset(self) -> None:
        super().reset()  # type: ignore[misc]
        self.input.reset()

    def feed(self, outputs: np.ndarray) -> None:
        """The step's model outputs (:func:`head_outputs`), read by the next :meth:`update`."""
        self.input.feed(outputs)

    def update(self, score: float, level: int = 0, stamp_ns: int = 0) -> BoundaryEvent | None:
        """Consume the next step (its outputs fed first); the boundary published now, if any."""
        return self.take(self.input.row(), score, level, stamp_ns)


class HeadDetector(FedByHead, HeadDecoder):
    """The boundary head as a streaming detector: :meth:`feed` the step's outputs, then :meth:`update`."""

    def __init__(self, head: BoundaryHead, config: DetectorConfig) -> None:
        self._attach(head)
        HeadDecoder.__init__(self, config, head.max_lag, head.peak)


def decode_rows(rows: np.ndarray, config: DetectorConfig, peak: bool) -> list[BoundaryEvent]:
    """Every boundary :class:`HeadDecoder` publishes over one episode's rows ``[T, max_lag + 1]``."""
    decoder = HeadDecoder(config, rows.shape[1] - 1, peak)
    events = [e for e in (decoder.take(r, 0.0) for r in rows) if e is not None]
    return events + decoder.close()


def decode_all(rows: Sequence[np.ndarray], config: DetectorConfig, peak: bool) -> list[list[BoundaryEvent]]:
    return [decode_rows(r, config, peak) for r in rows]


def decoded_steps(rows: np.ndarray, config: DetectorConfig, peak: bool) -> tuple[list[int], list[int]]:
    """(boundary steps, steps they are published at) of :func:`decode_rows`, without building the
    events: the same decisions over the rows that pass θ only (for scoring many rules at once;
    ``test/detect/test_boundary_head.py`` checks it against :class:`HeadDecoder`)."""
    length, lag, theta, gap = len(rows), int(config.lag), float(config.high), int(config.min_segment_length)
    steps: list[int] = []
    when: list[int] = []

    def fires(row: np.ndarray, s: int, j: int) -> bool:
        return (s >= 1 and (not steps or s - steps[-1] >= gap) and row[j] >= theta
                and not (peak and j > 0 and row[j - 1] > row[j]))

    taken = length if lag > 0 else length - 1  # lag 0: the last row is the final boundary itself
    for t in np.flatnonzero(rows[:taken, lag] >= theta).tolist():
        if fires(rows[t], t - lag, lag):
            steps.append(t - lag)
            when.append(min(t + 1, length - 1))
    for s in range(max(1, length - lag), length - 1):
        if fires(rows[length - 1], s, length - 1 - s):
            steps.append(s)
            when.append(length - 1)
    if not steps or steps[-1] < length - 1:
        steps.append(length - 1)
        when.append(length - 1)
    return steps, when


__all__ = [
    "HEAD_FILE", "BoundaryHead", "FedByHead", "HeadDecoder", "HeadDetector", "HeadInput", "decode_all",
    "decode_rows",
    "decoded_steps",
    "expected_shapes", "head_outputs", "load_head", "step_outputs", "windowed", "write_head",
]
