"""The live demo's monitor cuts its streams into episodes by the same rules as the offline replay."""

from __future__ import annotations

import numpy as np

from ompn_ros import layout
from ompn_ros.app.live import Streams, summarise
from ompn_ros.data.messages import SubtaskBoundary, encode_subtask_boundary


def _streams(boundary_steps: list[tuple[int, int]], steps: int = 6) -> Streams:
    streams = Streams()
    streams.ends.append({layout.KEY_STEPS: str(steps), layout.KEY_EPISODE: "0"})
    streams.obs_times = [1_000_000 * t for t in range(steps + 1)]
    streams.subtask = [0, 0, 0, 1, 1, 1][:steps]
    streams.pi_rows = [[0.5, 0.5, 1.5, 0.0]] * (steps + 1)
    for ordinal, (step, detected_at) in enumerate(boundary_steps):
        event = SubtaskBoundary(stamp_ns=step, frame_id="", node="/ompn_node", episode=1, step=step,
                                subtask=ordinal, subtask_id=-1, score=0.5, memory_level=1,
                                decided_step=detected_at, decided_stamp_ns=detected_at, final=False)
        streams.on_boundary(encode_subtask_boundary(event))  # the CDR the node publishes
        streams.boundaries[-1] = (streams.boundaries[-1][0], 1_000_000 * detected_at + 500_000)
    return streams


def test_boundary_on_the_done_observation_closes_the_last_real_step(tmp_path) -> None:
    # T = 6 real steps (0..5) and the done observation 6: a detection there is the final boundary 5
    episode = _streams([(2, 3), (6, 6)]).episodes()[0]
    assert episode.boundaries == [2, 5]
    assert episode.latencies_ms == [0.5, 0.5]
    summary = summarise([episode], tmp_path)
    assert summary["f1_tol0"] == 1.0 and summary["align_acc"] == 1.0


def test_done_step_boundary_and_final_boundary_are_not_counted_twice(tmp_path) -> None:
    episode = _streams([(2, 3), (5, 6), (6, 6)]).episodes()[0]
    assert episode.boundaries == [2, 5]
    assert np.isfinite(summarise([episode], tmp_path)["latency_ms_p50"])
