"""All episodes of a dataset in contiguous arrays (:class:`EpisodeArrays`), as the cache hands them to
training: built from episodes in memory or opened from a cache entry (:mod:`.entry`), memory-mapped."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..episode import Episode
from ..errors import CacheEntryError
from ..reader import BagFacts
from .entry import JOINT_KEYS, STEP_KEYS, common_obs_names, open_entry, write_entry


@dataclass
class EpisodeArrays:
    """All episodes of a dataset in contiguous arrays.

    Episode ``i`` has observations ``observations[obs_offsets[i]:obs_offsets[i+1]]`` (``T_i + 1``
    rows) and actions/subtask ``[act_offsets[i]:act_offsets[i+1]]`` (``T_i`` rows).  ``subtask`` is
    ``-1`` where an episode has no labels (``has_subtask[i]`` False); sketches are concatenated
    with ``sketch_offsets`` (``has_sketch[i]`` False = no sketch).  ``step_extras`` holds per-step
    arrays aligned with the actions (``subtask_id``), ``extras`` joint arrays aligned with the
    observations, each when every episode has them.  ``obs_names`` names the observation's elements
    (``Episode.extras['obs_names']``, e.g. from ``ReaderSpec.assemble``) when every episode has the
    same names, else it is empty.
    """

    observations: np.ndarray
    obs_offsets: np.ndarray
    actions: np.ndarray
    act_offsets: np.ndarray
    subtask: np.ndarray
    has_subtask: np.ndarray
    sketch: np.ndarray
    sketch_offsets: np.ndarray
    has_sketch: np.ndarray
    tasks: np.ndarray
    seeds: np.ndarray
    success: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    step_extras: dict[str, np.ndarray] = field(default_factory=dict)
    obs_names: tuple[str, ...] = ()
    report: str = ""  # ReadReport.summary() of the parse that built the arrays
    facts: tuple[BagFacts, ...] = ()  # ReadReport.facts() of that parse (none for synthetic episodes)
    key: str = ""
    cache_hit: bool = False
    cache_path: Path | None = None
    notes: list[str] = field(default_factory=list)  # entries found broken and rebuilt on the way

    def __len__(self) -> int:
        return len(self.obs_offsets) - 1

    def episode(self, i: int) -> Episode:
        """Episode ``i`` as an :class:`Episode` (arrays are views into this dataset)."""
        o0, o1 = self.obs_offsets[i], self.obs_offsets[i + 1]
        a0, a1 = self.act_offsets[i], self.act_offsets[i + 1]
        s0, s1 = self.sketch_offsets[i], self.sketch_offsets[i + 1]
        extras: dict[str, Any] = {k: v[o0:o1] for k, v in self.extras.items()}
        extras.update({k: v[a0:a1] for k, v in self.step_extras.items()})
        if self.obs_names:
            extras["obs_names"] = list(self.obs_names)
        return Episode(
            observations=self.observations[o0:o1],
            actions=self.actions[a0:a1],
            subtask=self.subtask[a0:a1] if self.has_subtask[i] else None,
            sketch=self.sketch[s0:s1] if self.has_sketch[i] else None,
            task=str(self.tasks[i]),
            seed=int(self.seeds[i]),
            success=bool(self.success[i]),
            extras=extras,
        )

    def episodes(self) -> list[Episode]:
        return [self.episode(i) for i in range(len(self))]

    @classmethod
    def from_episodes(cls, episodes: Sequence[Episode]) -> EpisodeArrays:
        """Concatenate ``episodes`` (all with the same observation size and action kind)."""
        if not episodes:
            raise ValueError("no episodes to concatenate")
        lengths = np.asarray([e.length for e in episodes], dtype=np.int64)
        act_offsets = np.concatenate([[0], np.cumsum(lengths)])
        obs_offsets = act_offsets + np.arange(len(episodes) + 1)
        sk = [np.zeros(0, np.int64) if e.sketch is None else np.asarray(e.sketch, np.int64) for e in episodes]
        sketch_offsets = np.concatenate([[0], np.cumsum([len(s) for s in sk])]).astype(np.int64)
        extras: dict[str, np.ndarray] = {}
        for key in JOINT_KEYS:
            if all(key in e.extras and len(e.extras[key]) == len(e.observations) for e in episodes):
                extras[key] = np.concatenate([np.asarray(e.extras[key]) for e in episodes])
        step_extras = {key: np.concatenate([np.asarray(e.extras[key]) for e in episodes])
                       for key in STEP_KEYS
                       if all(key in e.extras and len(e.extras[key]) == e.length for e in episodes)}
        return cls(
            observations=np.concatenate([e.observations for e in episodes]).astype(np.float32, copy=False),
            obs_offsets=obs_offsets.astype(np.int64),
            actions=np.concatenate([np.asarray(e.actions) for e in episodes]),
            act_offsets=act_offsets.astype(np.int64),
            subtask=np.concatenate([np.full(e.length, -1, np.int64) if e.subtask is None
                                    else np.asarray(e.subtask, np.int64) for e in episodes]),
            has_subtask=np.asarray([e.subtask is not None for e in episodes]),
            sketch=np.concatenate(sk),
            sketch_offsets=sketch_offsets,
            has_sketch=np.asarray([e.sketch is not None for e in episodes]),
            tasks=np.asarray([e.task for e in episodes], dtype=str),
            seeds=np.asarray([e.seed for e in episodes], dtype=np.int64),
            success=np.asarray([e.success for e in episodes]),
            extras=extras,
            step_extras=step_extras,
            obs_names=common_obs_names(episodes),
        )

    def _arrays(self) -> dict[str, np.ndarray]:
        names = ("observations", "obs_offsets", "actions", "act_offsets", "subtask", "has_subtask",
                 "sketch", "sketch_offsets", "has_sketch", "tasks", "seeds", "success")
        out = {n: getattr(self, n) for n in names}
        out.update({f"extras__{k}": v for k, v in self.extras.items()})
        out.update({f"step_extras__{k}": v for k, v in self.step_extras.items()})
        out["obs_names"] = np.asarray(self.obs_names, dtype=str)
        return out

    def save(self, path: Path, key: str = "") -> None:
        """Write as a cache entry: a directory of ``.npy`` files and ``index.json``, atomically."""
        write_entry(path, self._arrays(), self.report, key, self.facts)

    @classmethod
    def load(cls, path: Path, key: str | None = None) -> EpisodeArrays:
        """Open an entry written by :meth:`save` or :func:`load_arrays`, step arrays memory-mapped;
        ``key``: the identity it must have.

        Raises :class:`~ompn_ros.data.errors.CacheFormatError` (a ``ValueError``) for an entry
        of another format version, :class:`~ompn_ros.data.errors.CacheEntryError` for one whose
        key, checksums or offsets do not hold, and ``OSError`` when it is missing.
        """
        arrays, report, facts = open_entry(path, key)
        extras = {k[len("extras__"):]: arrays.pop(k) for k in list(arrays) if k.startswith("extras__")}
        step = {k[len("step_extras__"):]: arrays.pop(k) for k in list(arrays)
                if k.startswith("step_extras__")}
        names = tuple(str(n) for n in arrays.pop("obs_names"))
        try:
            out = cls(**arrays, extras=extras, step_extras=step, obs_names=names, report=report,
                      facts=facts, cache_path=path)
        except TypeError as exc:  # an array missing from the index, or one it should not have
            raise CacheEntryError(f"cache entry {path}: {exc}") from None
        out.check_layout()
        return out

    def check_layout(self) -> None:
        """Raise :class:`~ompn_ros.data.errors.CacheEntryError` unless the offsets cut the arrays into
        whole episodes (monotone, from 0 to each array's end, ``T + 1`` observations for ``T``
        actions) and every per-episode array has one value per episode.  O(episodes)."""
        n = len(self.obs_offsets) - 1
        obs, act, sk = (np.asarray(a, np.int64) for a in (self.obs_offsets, self.act_offsets,
                                                            self.sketch_offsets))
        per_episode = (self.has_subtask, self.has_sketch, self.tasks, self.seeds, self.success)
        problems = [
            n < 0 or len(act) != n + 1 or len(sk) != n + 1,
            n >= 0 and (obs[0] != 0 or act[0] != 0 or sk[0] != 0),
            bool(np.any(np.diff(act) < 0)) or bool(np.any(np.diff(sk) < 0)),
            len(obs) == len(act) and bool(np.any(obs != act + np.arange(n + 1))),
            n >= 0 and (obs[-1] != len(self.observations) or act[-1] != len(self.actions)
                        or act[-1] != len(self.subtask) or sk[-1] != len(self.sketch)),
            any(len(a) != n for a in per_episode),
        ]
        if any(problems):
            raise CacheEntryError(f"cache entry {self.cache_path}: its offsets do not cut its arrays into "
                                  f"{n} whole episodes")


__all__ = ["EpisodeArrays"]
