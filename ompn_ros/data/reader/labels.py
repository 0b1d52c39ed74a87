"""Subtask labels as users have them -> the 0-based ordinals metrics use.

``ordinal`` values are checked (never decreasing, below the sketch length), ``id`` values become
ordinals at every change, ``boundary`` events mark the last step of each subtask.  O(T) per episode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import LabelError


@dataclass(frozen=True)
class EpisodeLabels:
    """Ordinals ``[T]`` (``-1`` = missing) and, for ``id`` labels, the original ids ``[T]``."""

    ordinals: np.ndarray
    ids: np.ndarray | None = None


@dataclass(frozen=True)
class LabelSite:
    """Where an episode's labels come from, for error messages."""

    path: str
    topic: str
    episode: int  # index of the episode in its bag
    first_obs: int  # observation index range of the episode
    last_obs: int


def ordinals_from_values(values: np.ndarray, sketch_len: int | None, site: LabelSite) -> EpisodeLabels:
    """Check per-step ordinals (``-1`` = missing is allowed); raise :class:`LabelError` otherwise."""
    present = values[values >= 0]
    where = f"episode #{site.episode} (observations #{site.first_obs}..#{site.last_obs})"
    if present.size and (np.any(np.diff(present) < 0) or (values < -1).any()):
        shown = ", ".join(str(v) for v in present[:8]) + (", ..." if present.size > 8 else "")
        raise LabelError(f"{where}: subtask values {shown} are not ordinals (they decrease); if the "
                         "topic holds skill ids, set labels: id", path=site.path, topic=site.topic)
    if sketch_len and present.size and int(present.max()) >= sketch_len:
        raise LabelError(f"{where}: subtask ordinal {int(present.max())} is not below the sketch length "
                         f"{sketch_len}; if the topic holds skill ids, set labels: id",
                         path=site.path, topic=site.topic)
    return EpisodeLabels(values.astype(np.int64))


def ordinals_from_ids(ids: np.ndarray) -> EpisodeLabels:
    """A new ordinal at every change of id; a missing id (``-1``) continues the current subtask."""
    filled = ids.astype(np.int64)
    valid = np.flatnonzero(filled >= 0)
    if valid.size == 0:
        return EpisodeLabels(np.full(len(ids), -1, np.int64), filled)
    carry = np.maximum.accumulate(np.where(filled >= 0, np.arange(len(filled)), -1))
    filled = filled[np.maximum(carry, valid[0])]  # forward fill, the leading gap takes the first id
    change = np.concatenate([[0], (filled[1:] != filled[:-1]).astype(np.int64)])
    return EpisodeLabels(np.cumsum(change), ids.astype(np.int64))


def ordinals_from_events(events: np.ndarray, site: LabelSite) -> EpisodeLabels:
    """``events[t]`` True = step ``t`` ends a subtask; the last subtask ends at the episode's end."""
    if events.size > 1 and events.all():
        raise LabelError(f"episode #{site.episode} (observations #{site.first_obs}..#{site.last_obs}): "
                         "every step carries a boundary event; the topic looks like a per-step label, "
                         "set labels: ordinal or id", path=site.path, topic=site.topic)
    ends = events.astype(np.int64)
    return EpisodeLabels(np.concatenate([[0], np.cumsum(ends)[:-1]]).astype(np.int64))
