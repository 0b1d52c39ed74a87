"""Still observations: the model input without the steps on which nothing moved (``still_tolerance``).

People pause and hesitate while they demonstrate; a scripted expert does not.  A paused step repeats the
observation before it, and a model stepped on every such repeat both learns a "wait" habit from them and
sees boundaries in them (docs/design.md#still-observations).  A model whose config has
``still_tolerance > 0`` is stepped only on the observations that moved, by one rule for training, the
offline replay and ``ompn_node``:

* observation ``t`` of an episode is **still** when every element differs by less than
  ``still_tolerance`` from the last observation the model was stepped on; the first is never still;
* a still observation is not stepped; it joins the **run** of the stepped observation before it, and
  that run's step takes the action and the subtask label of the run's *last* row (the action that
  moved the robot on);
* a step's boundary is placed at the last row of its run, so a pause belongs to the subtask it
  follows in the stream, and every boundary keeps the row and stamp of the original stream.

:class:`StillRuns` is the rule for one observation at a time (O(1) per observation, no allocation but a
copy of the stepped observation) and its one applier: :func:`still_runs` turns it on for a tolerance,
:meth:`StillRuns.apply` steps a model only on the observations that moved (the stream rule of
``ompn_node`` and the replay, :mod:`ompn_ros.stream.rule`; the closed loop), :func:`drop_still` pushes a
whole :class:`Episode` through it (training).  It is also the one row mapper: :meth:`StillRuns.end_of`
gives the row and stamp a step's output and boundary belong to, :meth:`StillRuns.run_of` the rows of
its run.  "Still" is this rule's word only; the idle rule's word for a step that does not move is
"idle" (:mod:`.idle`).

``still_tolerance: auto`` (``ompn_train``'s default) chooses T from the training episodes, without labels
(:func:`choose_tolerance`, docs/design.md#still-observations): T sits above the observations' own noise
floor, so a held pose is still and a move is not, and it is 0 when the data has no noise floor (a
scripted demonstrator on a noise-free sim), when almost nothing would be still at T, or when pauses
cannot be told from slow motion (continuous control whose slow approach moves by a few noise floors a
step: thinning it would drop moving steps too).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from ompn_ros.data.episode import Episode

__all__ = ["AUTO", "StillChoice", "StillRuns", "check_setting", "check_tolerance", "choose_tolerance",
           "drop_still", "element_noise", "noise_floor", "noise_margin", "run_ends", "still_runs"]

Out = TypeVar("Out")

AUTO = "auto"
"""``still_tolerance: auto``: T chosen from the training episodes (:func:`choose_tolerance`)."""
AUTO_MARGIN = 2.0
"""Noise floors above the largest of ``n`` noise differences that T adds (:func:`choose_tolerance`)."""
AUTO_MIN_STILL_SHARE = 0.01
"""``auto`` keeps T = 0 when fewer than this share of the steps would be still at the chosen T."""
AUTO_BAND = 4.0
"""``auto`` keeps T = 0 when at least :data:`AUTO_MIN_STILL_SHARE` of the steps change by between T and
this many T (in their largest element): slow motion that a tolerance would thin like a pause."""
AUTO_SAMPLE_STEPS = 20000
"""At most this many steps (whole episodes, spread over the data) estimate the noise floor."""
_QUARTER = 0.25
_QUARTER_TO_STD = 1.0 / 0.3186  # |N(0, s)|: its lower quartile is 0.3186 s


def element_noise(values: np.ndarray) -> np.ndarray:
    """Per element of ``values`` ``[steps, elements]`` (one stream in time order), the noise of its change
    per step: the standard deviation the change would have if nothing moved, from the lower quartile of
    the absolute second differences (a smooth motion barely bends them, white sensor noise of standard
    deviation s gives changes of s·√2 and second differences of s·√6; the quartile reads the floor even
    when most steps move).  0 where the element repeats exactly; empty with fewer than 3 steps."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or len(values) < 3:
        return np.zeros(0)
    bends = np.abs(np.diff(values, n=2, axis=0))
    return np.quantile(bends, _QUARTER, axis=0) * _QUARTER_TO_STD / np.sqrt(3.0)


def noise_margin(elements: int) -> float:
    """How many noise floors lie above the largest of ``elements`` pure-noise changes:
    √(2 ln 2n) + :data:`AUTO_MARGIN` (the factor of ``still_tolerance: auto`` and ``idle_speed: auto``)."""
    return float(np.sqrt(2.0 * np.log(2.0 * max(int(elements), 1))) + AUTO_MARGIN)


def check_tolerance(value: object, name: str = "still_tolerance") -> float:
    """``value`` as a float ≥ 0 (0 = every observation is stepped), else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0 (0 = off), got {value!r}")
    return float(value)


def check_setting(value: object, name: str = "still_tolerance") -> float | str:
    """A config's setting: ``'auto'`` or a tolerance (:func:`check_tolerance`); a ValueError naming
    ``name`` and both forms otherwise."""
    if isinstance(value, str) and value.strip().lower() == AUTO:
        return AUTO
    try:
        return check_tolerance(value, name)
    except ValueError:
        raise ValueError(f"{name} must be 'auto' (chosen from the training data) or a finite number >= 0 "
                         f"(0 = off), got {value!r}") from None


@dataclass(frozen=True)
class StillChoice:
    """What ``still_tolerance: auto`` chose: ``tolerance`` (0 = off), the ``noise`` floor it rests on (the
    robust standard deviation of one element's change per step while nothing moves), the share of steps
    still at ``tolerance``, and why, in words (the read summary's line)."""

    tolerance: float
    noise: float
    still_share: float
    reason: str

    def summary(self) -> str:
        """One line for the read summary."""
        return f"still_tolerance: auto -> {self.tolerance:.6g} ({self.reason})"

    def as_dict(self) -> dict[str, object]:
        return {"tolerance": self.tolerance, "noise": self.noise, "still_share": self.still_share,
                "reason": self.reason}


def _sample(episodes: Sequence[Episode], limit: int) -> list[np.ndarray]:
    """The real-step observations of whole episodes spread evenly over ``episodes``, ≤ ``limit`` steps
    (at least one episode)."""
    total = sum(ep.length for ep in episodes)
    stride = max(1, int(np.ceil(total / max(limit, 1))))
    return [np.asarray(ep.observations[: ep.length], dtype=np.float64) for ep in episodes[::stride]]


def noise_floor(episodes: Sequence[Episode], limit: int = AUTO_SAMPLE_STEPS) -> float:
    """The observations' noise floor: the median over elements of :func:`element_noise`, over the
    episodes' second differences (never across two episodes).  0 for noise-free data."""
    bends = [np.abs(np.diff(obs, n=2, axis=0)) for obs in _sample(episodes, limit) if len(obs) >= 3]
    if not bends:
        return 0.0
    per_element = np.quantile(np.concatenate(bends), _QUARTER, axis=0) * _QUARTER_TO_STD / np.sqrt(3.0)
    return float(np.median(per_element))


def choose_tolerance(episodes: Sequence[Episode], limit: int = AUTO_SAMPLE_STEPS) -> StillChoice:
    """``still_tolerance: auto``: T = noise · :func:`noise_margin` of the ``n`` observation elements (the
    largest of ``n`` pure-noise changes stays below it), 0 without a noise floor or when
    fewer than :data:`AUTO_MIN_STILL_SHARE` of the sampled steps would be still, or when at least that
    share changes by between T and :data:`AUTO_BAND` T (pauses and moves not separated).  No labels are
    read."""
    sample = [ep for ep in episodes if ep.length > 0]
    if not sample:
        return StillChoice(0.0, 0.0, 0.0, "no steps to measure")
    noise = noise_floor(sample, limit)
    if not noise > 0:
        return StillChoice(0.0, 0.0, 0.0, "no noise floor: the observations repeat exactly, none held still")
    elements = int(sample[0].observations.shape[1]) if sample[0].observations.ndim == 2 else 1
    tolerance = noise * noise_margin(elements)
    stride = max(1, int(np.ceil(sum(ep.length for ep in sample) / max(limit, 1))))
    picked = sample[::stride]
    steps = sum(ep.length for ep in picked)
    still = steps - sum(drop_still(ep, tolerance)[0].length for ep in picked)
    share = still / max(steps, 1)
    changes = np.concatenate([np.abs(np.diff(np.asarray(ep.observations[: ep.length], dtype=np.float64),
                                                    axis=0)).max(axis=1, initial=0.0) for ep in picked])
    band = float(np.mean((changes >= tolerance) & (changes < AUTO_BAND * tolerance))) if changes.size else 0.0
    if band >= AUTO_MIN_STILL_SHARE:
        return StillChoice(0.0, noise, share, f"noise floor {noise:.3g}; {100 * band:.1f} % of the steps "
                           f"move by {tolerance:.3g} to {AUTO_BAND:g}x that: slow moves look like pauses: "
                           "off")
    if share < AUTO_MIN_STILL_SHARE:
        return StillChoice(0.0, noise, share, f"noise floor {noise:.3g}; only {100 * share:.1f} % of the "
                           f"steps still at {tolerance:.3g}, below {100 * AUTO_MIN_STILL_SHARE:.0f} %: off")
    return StillChoice(tolerance, noise, share, f"noise floor {noise:.3g} per element and step; "
                       f"{100 * share:.1f} % of the steps still")


@dataclass
class StillRuns:
    """The still rule over one episode's observations, in arrival order (see the module docstring).

    :meth:`push` says whether an observation is stepped; ``firsts[j]`` is the row of step ``j``'s
    observation, ``ends[j]`` / ``stamps[j]`` the row and stamp of the last observation of its run so far
    (rows count every pushed observation of the episode).
    """

    tolerance: float
    rows: int = 0
    firsts: list[int] = field(default_factory=list)
    ends: list[int] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    priors: list[int] = field(default_factory=list)  # the stamp of the row before ends[j] in its run
    _last: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.tolerance = check_tolerance(self.tolerance)

    def reset(self) -> None:
        """A new episode: nothing pushed yet."""
        self.rows, self._last = 0, None
        self.firsts.clear()
        self.ends.clear()
        self.stamps.clear()
        self.priors.clear()

    def is_still(self, obs: np.ndarray) -> bool:
        """Whether ``obs`` is within the tolerance of the last stepped observation (nothing changes)."""
        last = self._last
        return last is not None and bool(np.all(np.abs(obs - last) < self.tolerance))

    def apply(self, obs: np.ndarray, stamp_ns: int, step: Callable[[np.ndarray], Out]) -> Out | None:
        """The rule in front of a model: ``step(obs)`` when ``obs`` moved (it starts a run), None when it
        is still (it joins the open run, the model is not stepped)."""
        return step(obs) if self.push(obs, stamp_ns) else None

    def push(self, obs: np.ndarray, stamp_ns: int = 0) -> bool:
        """One observation of the episode: True when it is stepped (it starts a run), False when it is
        still (it extends the open run)."""
        row = self.rows
        self.rows += 1
        if self.is_still(obs):
            self.priors[-1] = self.stamps[-1]
            self.ends[-1], self.stamps[-1] = row, int(stamp_ns)
            return False
        self._last = np.array(obs, dtype=np.float32, copy=True)
        self.firsts.append(row)
        self.ends.append(row)
        self.stamps.append(int(stamp_ns))
        self.priors.append(int(stamp_ns))
        return True

    @property
    def steps(self) -> int:
        """How many observations were stepped in this episode."""
        return len(self.ends)

    def end_of(self, step: int, last_row: int | None = None) -> tuple[int, int]:
        """``(row, stamp)`` of the last observation of step ``step``'s run, at most ``last_row`` (the
        episode's last real step when it closes: the final observation, row ``last_row + 1``, is no step
        of a run, so the run that holds ``last_row`` ends there)."""
        j = min(max(step, 0), len(self.ends) - 1)
        if last_row is not None and self.ends[j] > last_row:
            j = min(j, int(np.searchsorted(np.asarray(self.firsts), last_row, side="right")) - 1)
            if self.ends[j] > last_row:  # the final observation extended this run: its row before
                return last_row, self.priors[j]
        return self.ends[j], self.stamps[j]

    def run_of(self, step: int, last_row: int) -> tuple[int, int]:
        """``(first, last)`` rows of step ``step``'s run (``firsts[step] <= last_row``), the last at most
        ``last_row`` (:meth:`end_of`)."""
        return self.firsts[step], self.end_of(step, last_row)[0]

    def steps_before(self, row: int) -> int:
        """How many stepped observations lie at rows ``< row`` (an end marker's step count, mapped)."""
        return int(np.searchsorted(np.asarray(self.firsts), row, side="left"))


def still_runs(tolerance: float) -> StillRuns | None:
    """The still rule of a model whose ``still_tolerance`` is ``tolerance`` (checked): a fresh
    :class:`StillRuns`, or None when it is off (0: every observation is stepped)."""
    return StillRuns(tolerance) if check_tolerance(tolerance) > 0 else None


def run_ends(first_rows: np.ndarray, length: int) -> np.ndarray:
    """The last row of each run whose first rows are ``first_rows`` in an episode of ``length`` steps."""
    first_rows = np.asarray(first_rows, dtype=np.int64)
    return np.append(first_rows[1:] - 1, length - 1).astype(np.int64)


def drop_still(episode: Episode, tolerance: float) -> tuple[Episode, np.ndarray]:
    """``(episode without its still steps, the first row of each step's run)`` (module docstring).

    The rule runs over the ``T`` real steps; the final observation (row ``T``) stays the final one.  Per-row
    extras follow their rows (per-observation arrays the run's first row, per-step arrays its last).
    With a tolerance of 0 the episode is returned as it is.
    """
    T = episode.length
    runs = still_runs(tolerance)
    if runs is None or T == 0:
        return episode, np.arange(T, dtype=np.int64)
    first = np.array([t for t in range(T) if runs.push(episode.observations[t])], dtype=np.int64)
    last = run_ends(first, T)
    obs_rows = np.append(first, T)
    extras = {}
    for key, value in episode.extras.items():
        arr = value if isinstance(value, np.ndarray) else None
        if arr is not None and arr.ndim >= 1 and len(arr) == T + 1:
            extras[key] = arr[obs_rows]
        elif arr is not None and arr.ndim >= 1 and len(arr) == T:
            extras[key] = arr[last]
        else:
            extras[key] = value
    reduced = Episode(
        np.ascontiguousarray(episode.observations[obs_rows]),
        np.ascontiguousarray(episode.actions[last]),
        None if episode.subtask is None else episode.subtask[last],
        episode.sketch, episode.task, episode.seed, episode.success, extras,
    )
    return reduced, first
