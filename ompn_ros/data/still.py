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
copy of the stepped observation); :func:`drop_still` runs it over a whole :class:`Episode`; the stream
rule (:mod:`ompn_ros.stream.rule`) runs it live and maps boundaries back with :meth:`StillRuns.end_of`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ompn_ros.data.episode import Episode

__all__ = ["StillRuns", "check_tolerance", "drop_still", "run_ends"]


def check_tolerance(value: object, name: str = "still_tolerance") -> float:
    """``value`` as a float ≥ 0 (0 = every observation is stepped), else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0 (0 = off), got {value!r}")
    return float(value)


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

    def steps_before(self, row: int) -> int:
        """How many stepped observations lie at rows ``< row`` (an end marker's step count, mapped)."""
        return int(np.searchsorted(np.asarray(self.firsts), row, side="left"))


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
    if check_tolerance(tolerance) == 0 or T == 0:
        return episode, np.arange(T, dtype=np.int64)
    runs = StillRuns(tolerance)
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
