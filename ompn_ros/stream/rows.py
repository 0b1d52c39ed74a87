"""The rows of an episode's stream: which observations the still rule steps, and steps as rows.

With a model whose ``still_tolerance`` is above 0, an observation that moved nothing since the last
stepped one is not stepped (:mod:`ompn_ros.data.cuts.still`); the steps and boundaries the stream rule
(:mod:`ompn_ros.stream.rule`) gives out keep the stream's rows all the same.  :class:`EpisodeRows` is the
rule's part that holds the still runs of one episode and maps the segmenter's steps to rows; without
``still_tolerance`` every observation is a step and nothing is mapped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ompn_ros.data.cuts import StillRuns, still_runs
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.segmenter import SegmenterOutput

__all__ = ["EpisodeRows"]


class EpisodeRows:
    """The still runs of one episode (:attr:`runs`: ``None`` until the first observation of a model with a
    ``still_tolerance``, and for a model without) and the mapping of its steps to the stream's rows."""

    def __init__(self) -> None:
        self.runs: StillRuns | None = None

    def forget(self) -> None:
        """A new episode (or a new segmenter): no runs yet."""
        self.runs = None

    def hold(self, tolerance: float) -> Callable[[np.ndarray, int], bool] | None:
        """The still rule the segmenter asks whether an observation is stepped (:func:`still_runs`; the
        episode's runs start with its first observation), ``None`` when ``tolerance`` is 0."""
        if self.runs is None and tolerance > 0:
            self.runs = still_runs(tolerance)
        return None if self.runs is None else self.runs.push

    def last(self, step_index: int) -> int:
        """The row of the episode's last observation given to the segmenter (``step_index``, the index of
        its last step, without still runs)."""
        return step_index if self.runs is None else self.runs.rows - 1

    def steps_before(self, rows: int | None) -> int | None:
        """An end marker's count of rows as a count of steps (:meth:`StillRuns.steps_before`)."""
        return rows if self.runs is None or rows is None else self.runs.steps_before(rows)

    def output(self, out: SegmenterOutput) -> SegmenterOutput:
        """A step's output with its step and boundary as rows and stamps of the stream."""
        if self.runs is None:
            return out
        return replace(out, boundary=self.event(out.boundary), step_index=self.runs.firsts[-1])

    def event(self, event: BoundaryEvent | None, last_row: int | None = None) -> BoundaryEvent | None:
        """``event`` with its steps as rows of the stream (:meth:`StillRuns.end_of`): a step's boundary at
        the last row of its run (``last_row``: at most the episode's last real step); unchanged without
        ``still_tolerance``."""
        runs = self.runs
        if event is None or runs is None or runs.steps == 0:
            return event
        row, stamp = runs.end_of(event.step, last_row)
        detected = runs.end_of(event.detected_at, last_row)[0]
        return replace(event, step=row, detected_at=max(detected, row),
                       stamp_ns=stamp if event.stamp_ns else event.stamp_ns)
