"""One stream rule live and offline: a recorded stream with an out-of-order stamp, a clock jump back and
a pause, replayed with its stamps (:func:`ompn_ros.stream.replay.replay_stream`), is cut into the
episodes the rules say, each segmented as a fresh episode; and ``ompn_node`` fed the same stream
publishes the replay's steps and boundaries, number for number."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from random_checkpoint import random_checkpoint  # noqa: E402

from ompn_ros.detect.online import BoundaryEvent, DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import StreamRecord, replay_stream  # noqa: E402
from ompn_ros.stream.rule import StreamLimits  # noqa: E402
from ompn_ros.validate import OutOfOrderStamp  # noqa: E402

OBS_DIM = 6
S = 1_000_000_000
MS = 1_000_000
DETECTOR = DetectorConfig(high=0.3, low=0.3)
LIMITS = StreamLimits(clock_jump_back=1.0, episode_gap=0.5)
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "stream", seed=5,
                             obs_dim=OBS_DIM, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)


def stream() -> tuple[np.ndarray, list[int], list[list[int]]]:
    """Observations, their stamps, and the rows of each episode the rules make of them: episode 1 (one
    row stamped 10 ms before its predecessor: rejected), a clock restart 30 s back (episode 2), a
    pause of 2 s (episode 3)."""
    obs = np.random.default_rng(7).normal(size=(40, OBS_DIM)).astype(np.float32)
    stamps = [100 * S + 40 * MS * t for t in range(14)]
    stamps[9] = stamps[8] - 10 * MS  # out of order, less than clock_jump_back: skipped
    stamps += [70 * S + 40 * MS * t for t in range(12)]  # the source's clock restarted
    stamps += [stamps[-1] + 2 * S + 40 * MS * t for t in range(14)]  # after a pause > episode_gap
    episodes = [[r for r in range(14) if r != 9], list(range(14, 26)), list(range(26, 40))]
    return obs, stamps, episodes


def fresh_episode(ckpt: Path, obs: np.ndarray, stamps: list[int], closed: bool) -> list[BoundaryEvent]:
    """One episode on a fresh segmenter, closed at its last step (by the next episode's cut) or open."""
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    events = [e for x, s in zip(obs, stamps, strict=True) if (e := seg.step(x, s).boundary) is not None]
    return events + seg.end_episode(len(obs) - 1) if closed else events


def test_replay_cuts_the_stream_where_the_rules_say(ckpt: Path) -> None:
    obs, stamps, episodes = stream()
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    record = replay_stream(seg, obs, stamps, LIMITS)
    assert [type(e) for e in record.rejections] == [OutOfOrderStamp]
    assert record.events["clock_jumps"] == 1 and record.events["episode_gaps"] == 1
    assert [ep for ep, _, _ in record.steps] == [k + 1 for k, rows in enumerate(episodes) for _ in rows]
    assert [stamp for _, stamp, _ in record.steps] == [stamps[r] for rows in episodes for r in rows]
    for k, rows in enumerate(episodes):
        want = fresh_episode(ckpt, obs[rows], [stamps[r] for r in rows], closed=k < len(episodes) - 1)
        got = [event for ep, _, event in record.boundaries if ep == k + 1]
        assert got == want and any(e.final for e in got) == (k < len(episodes) - 1)
    assert any(event.final for _, _, event in record.boundaries)


def node_outputs(ctx, ckpt: Path, obs: np.ndarray, stamps: list[int]) -> tuple[list[tuple], np.ndarray, Any]:
    """The stream through an active ompn_node in process: its ~/boundary events, ~/pi rows, detector."""
    from node_in_process import active_node

    from ompn_ros.data import messages as m
    from ompn_ros.data.messages import decode_subtask_boundary

    node = active_node(ctx, ckpt, max_stamp_lead=0.0, clock_jump_back=1.0, episode_gap=0.5)
    for x, s in zip(obs, stamps, strict=True):
        node.inputs.on_raw_array(m.encode_float32_array(x), s)
    boundaries = []
    for raw in node.outputs.pubs["boundary"].raws:
        b = decode_subtask_boundary(raw)
        boundaries.append((b.episode, b.step, b.subtask, b.final, b.stamp_ns, b.decided_stamp_ns,
                           np.float32(b.score)))
    pis = np.array([m.parse_float32_array(raw) for raw in node.outputs.pubs["pi"].raws])
    assert node.counters()["rejected_out_of_order_stamp"] == 1
    config = node.segmenter.detector_config
    node.destroy_node()
    return boundaries, pis, config


def replay_outputs(record: StreamRecord) -> tuple[list[tuple], np.ndarray]:
    """The same numbers from the replay's record (the ~/pi layout: π_1..π_n, Σ i·π_i, π_end)."""
    boundaries = [(ep, e.step, e.subtask, e.final, e.stamp_ns, decided, np.float32(e.score))
                  for ep, decided, e in record.boundaries]
    pis = np.array([np.concatenate([np.asarray(out.step_output.pi, np.float32),
                                    np.float32([out.step_output.expected_position, out.step_output.pi_end])])
                    for _, _, out in record.steps])
    return boundaries, pis


def test_the_node_publishes_what_the_replay_gives(ctx, ckpt: Path) -> None:
    pytest.importorskip("rclpy")
    obs, stamps, _ = stream()
    live_boundaries, live_pis, config = node_outputs(ctx, ckpt, obs, stamps)
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), config)
    offline_boundaries, offline_pis = replay_outputs(replay_stream(seg, obs, stamps, LIMITS))
    assert live_boundaries == offline_boundaries and {b[0] for b in live_boundaries if b[3]} == {1, 2}
    assert live_pis.shape == offline_pis.shape == (len(obs) - 1, 3 + 2)
    np.testing.assert_array_equal(live_pis, offline_pis)
