"""Still observations (``still_tolerance``, ompn_ros.data.cuts.still): one rule for training, replay, node."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from random_checkpoint import random_checkpoint  # noqa: E402

from ompn_ros.data.cuts import StillRuns, check_tolerance, drop_still, run_ends  # noqa: E402
from ompn_ros.data.episode import Episode  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.errors import ConfigError  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode, replay_stream  # noqa: E402
from ompn_ros.stream.rule import StreamLimits  # noqa: E402

OBS_DIM = 6
TOL = 0.2
MS = 1_000_000
DETECTOR = DetectorConfig(high=0.4, low=0.38)  # fires on this random model's scores (0.33-0.45)
torch.set_num_threads(1)


def paused_episode(seed: int = 11, steps: int = 60) -> tuple[Episode, list[int]]:
    """An episode whose rows repeat the one before (a pause, with noise below the tolerance) at random;
    returns it and the rows that moved (the first of each run)."""
    rng = np.random.default_rng(seed)
    obs = np.empty((steps + 1, OBS_DIM), np.float32)
    moved = []
    for t in range(steps + 1):
        if t == 0 or t == steps or rng.random() > 0.4:
            obs[t] = rng.normal(size=OBS_DIM)
            moved.append(t)
        else:
            obs[t] = obs[t - 1] + rng.uniform(-0.05, 0.05, OBS_DIM)
    actions = rng.normal(size=(steps, 2)).astype(np.float32)
    subtask = np.repeat(np.arange(4), steps // 4)
    ep = Episode(obs, actions, subtask, None, "paused", seed, True,
                 {"joint": np.arange(steps + 1), "per_step": np.arange(steps)})
    return ep, [t for t in moved if t < steps]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "still", seed=5, obs_dim=OBS_DIM, action_type="continuous",
                             action_dim=2, n_slots=3, slot_size=16, still_tolerance=TOL)


def test_drop_still_keeps_the_rows_that_moved_with_the_action_and_label_of_each_runs_last_row() -> None:
    ep, moved = paused_episode()
    short, first = drop_still(ep, TOL)
    assert first.tolist() == moved and short.length == len(moved) < ep.length
    last = run_ends(first, ep.length)
    assert last.tolist() == [*(np.array(moved[1:]) - 1), ep.length - 1]
    np.testing.assert_array_equal(short.observations[:-1], ep.observations[first])
    np.testing.assert_array_equal(short.observations[-1], ep.observations[-1])  # the final observation stays
    np.testing.assert_array_equal(short.actions, ep.actions[last])
    np.testing.assert_array_equal(short.subtask, ep.subtask[last])
    assert short.extras["joint"].tolist() == [*moved, ep.length]
    assert short.extras["per_step"].tolist() == last.tolist()
    again, first_again = drop_still(short, TOL)  # idempotent: every kept row moved from the one before
    assert again.length == short.length and first_again.tolist() == list(range(short.length))
    assert drop_still(ep, 0.0)[0] is ep


def test_a_run_ends_where_the_next_step_starts_and_markers_count_rows() -> None:
    runs = StillRuns(TOL)
    values = [0.0, 0.1, 0.19, 1.0, 1.0, 0.0]
    pushed = [runs.push(np.full(2, v, np.float32), 10 * i) for i, v in enumerate(values)]
    assert pushed == [True, False, False, True, False, True]  # against the last stepped row, not the last row
    assert runs.firsts == [0, 3, 5] and runs.ends == [2, 4, 5] and runs.steps == 3
    assert runs.end_of(0) == (2, 20) and runs.end_of(1) == (4, 40)
    assert runs.end_of(2, last_row=4) == (4, 40)  # a last step of its own at the final row: the run before
    runs.push(np.full(2, 0.0, np.float32), 60)  # the final observation (row 6) extends the last run
    assert runs.end_of(2, last_row=5) == (5, 50) and runs.end_of(0, last_row=5) == (2, 20)
    assert [runs.steps_before(r) for r in (0, 1, 3, 4, 5, 6)] == [0, 1, 1, 2, 2, 3]
    drift = StillRuns(TOL)
    drifting = [drift.push(np.full(1, 0.15 * i, np.float32)) for i in range(4)]
    assert drifting == [True, False, True, False]
    for bad in (-0.1, float("nan"), True, "0.2"):
        with pytest.raises(ValueError, match="still_tolerance"):
            check_tolerance(bad)
    with pytest.raises(ConfigError, match=r"OMPNConfig\.still_tolerance"):
        OMPNConfig(obs_dim=3, action_type="discrete", action_dim=2, still_tolerance=-1)


def test_replay_of_a_paused_episode_is_the_replay_of_its_moves_on_the_streams_rows(ckpt: Path) -> None:
    ep, _ = paused_episode()
    short, first = drop_still(ep, TOL)
    last = run_ends(first, ep.length)
    full = replay_episode(StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR), ep)
    moves = replay_episode(StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR), short)
    assert len(full.p_hat) == ep.length and len(moves.p_hat) == short.length
    np.testing.assert_allclose(full.p_hat[last], moves.p_hat, atol=1e-6)  # a step's output at its run's end
    still_rows = np.setdiff1d(np.arange(ep.length), last)
    assert len(still_rows) and np.all(full.scores[still_rows] == 0)
    assert np.all(full.p_hat[still_rows, -1] == 1)
    np.testing.assert_allclose(full.pi[still_rows], moves.pi[np.searchsorted(last, still_rows)],
                               atol=1e-6)  # the memory holds through a pause
    assert len(moves.boundaries) > 2, "the detector must fire for the comparison to mean anything"
    assert [b.step for b in full.boundaries] == [int(last[b.step]) for b in moves.boundaries]
    assert [(b.subtask, b.final) for b in full.boundaries] == [(b.subtask, b.final) for b in moves.boundaries]
    assert full.boundaries[-1].step == ep.length - 1 and full.boundaries[-1].final


def test_the_stream_replay_steps_only_moves_and_stamps_boundaries_with_the_streams_rows(ckpt: Path) -> None:
    ep, moved = paused_episode(seed=11, steps=60)
    stamps = [100 * 10**9 + 40 * MS * t for t in range(ep.length + 1)]
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    record = replay_stream(seg, ep.observations, stamps, StreamLimits())
    assert [out.step_index for _, _, out in record.steps] == [*moved, ep.length]
    assert [stamp for _, stamp, _ in record.steps] == [stamps[t] for t in [*moved, ep.length]]
    assert record.events["still_observations"] == ep.length - len(moved)
    last = run_ends(np.array(moved), ep.length)
    assert record.boundaries
    for _, decided, event in record.boundaries:
        assert event.step in last and event.stamp_ns == stamps[event.step] and event.detected_at > event.step
        assert decided in stamps and decided >= event.stamp_ns


def test_a_model_without_the_tolerance_steps_every_observation(tmp_path_factory: pytest.TempPathFactory
                                                               ) -> None:
    plain = random_checkpoint(tmp_path_factory, "plain", seed=5, obs_dim=OBS_DIM, action_type="continuous",
                              action_dim=2, n_slots=3, slot_size=16)
    seg = StreamingSegmenter(stepper_from_checkpoint(plain), DETECTOR)
    assert seg.still_tolerance == 0
    ep, _ = paused_episode()
    stamps = [10 * MS * (t + 1) for t in range(ep.length + 1)]
    record = replay_stream(seg, ep.observations, stamps, StreamLimits())
    assert [out.step_index for _, _, out in record.steps] == list(range(ep.length + 1))
    assert "still_observations" not in record.events


def test_training_steps_the_model_on_the_moves_only() -> None:
    from ompn_ros.train import trainer

    ep, moved = paused_episode()
    config = OMPNConfig(obs_dim=OBS_DIM, action_type="continuous", action_dim=2, still_tolerance=TOL)
    got = trainer._without_still([ep, replace(ep, seed=4)], config.still_tolerance, trainer.DistContext())
    assert [e.length for e in got] == [len(moved)] * 2
    assert trainer._without_still([ep], 0.0, trainer.DistContext())[0] is ep


def test_the_node_live_publishes_what_the_replay_gives_on_a_paused_stream(ctx, ckpt: Path) -> None:
    pytest.importorskip("rclpy")
    from episode_markers import marker
    from node_in_process import active_node

    from ompn_ros.data import messages as m
    from ompn_ros.data.messages import decode_subtask_boundary

    ep, moved = paused_episode()
    stamps = np.array([100 * 10**9 + 40 * MS * t for t in range(ep.length + 1)])
    node = active_node(ctx, ckpt, detector_high=0.4, detector_hysteresis=0.02, max_stamp_lead=0.0)
    node.inputs.markers.on_episode(marker("start"))
    for x, s in zip(ep.observations, stamps, strict=True):
        node.inputs.on_raw_array(m.encode_float32_array(x), int(s))
    node.inputs.markers.on_episode(marker("end", steps=str(ep.length)))
    live = [(b.step, b.subtask, b.final, b.stamp_ns)
            for b in map(decode_subtask_boundary, node.outputs.pubs["boundary"].raws)]
    states, node_counters = len(node.outputs.pubs["state"].raws), node.counters()
    node.destroy_node()
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    replay = replay_episode(seg, ep, include_done_step=True, stamps_ns=stamps)
    assert len(replay.published) > 2
    assert live == [(b.step, b.subtask, b.final, b.stamp_ns) for b in replay.published]
    assert all(b.stamp_ns == stamps[b.step] for b in replay.published)  # the closing ones too
    assert states == len(moved) + 1  # one ~/state per stepped observation (the final one moved too)
    assert node_counters["still_observations"] == ep.length - len(moved)


def test_a_detector_decoded_again_from_the_replay_reads_the_stepped_rows(ckpt: Path) -> None:
    from ompn_ros.detect.tune import compare_on_replays, score_online

    ep, moved = paused_episode()
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    full = replay_episode(seg, ep)
    assert full.run_ends is not None
    assert full.run_ends.tolist() == run_ends(np.array(moved), ep.length).tolist()
    want = [b.step for b in full.boundaries]
    labelled = replace(ep, subtask=np.repeat(np.arange(len(want)), np.diff([-1, *want])))
    assert score_online([full], [labelled], DETECTOR)["f1_tol0"] == 1.0  # the node's boundaries, exactly
    offline = compare_on_replays([full], [labelled], {"online": DETECTOR})["offline_topk"]
    assert offline["f1_tol1"] > 0 and set(np.flatnonzero(full.scores)) <= set(full.run_ends.tolist())


def test_in_the_loop_a_still_observation_gives_the_last_steps_output_again(ckpt: Path) -> None:
    from ompn_ros.app.closed_loop import StillAgent, policy_agent
    from ompn_ros.model.checkpoint import load_checkpoint

    agent = policy_agent(load_checkpoint(ckpt)[0])
    assert isinstance(agent, StillAgent)
    ep, moved = paused_episode()
    agent.reset()
    outs = [agent.step(x) for x in ep.observations[:-1]]
    assert len({id(o) for o in outs}) == len(moved)  # one output per run, repeated through the pause
    stepper = stepper_from_checkpoint(ckpt)
    stepper.reset()
    direct = [stepper.step(ep.observations[t]) for t in moved]
    firsts = [outs[t] for t in moved]
    np.testing.assert_allclose([o.p_hat for o in firsts], [o.p_hat for o in direct], atol=1e-5)


def test_the_node_with_the_tolerance_on_a_human_like_craft_stream_equals_its_replay(ctx, tmp_path: Path
                                                                                    ) -> None:
    """The shipped Craft model with ``still_tolerance`` set, on what ``craft_sim demonstrator:=human``
    publishes (pauses, detours, sensor noise, dropped and duplicated messages)."""
    pytest.importorskip("rclpy")
    import json
    import shutil
    import time

    from human_streams import Recorder, _episodes, live, received
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.parameter import Parameter

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.nodes.ompn_node import OMPNNode

    still_dir = tmp_path / "craft_still"
    shutil.copytree(shipped_checkpoint("craft"), still_dir)
    config = json.loads((still_dir / "config.json").read_text())
    (still_dir / "config.json").write_text(json.dumps({**config, "still_tolerance": TOL}))
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("checkpoint", value=str(still_dir))])
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node.outputs.pubs = {k: Recorder() for k in node.outputs.pubs}
    seg = node.segmenter
    assert seg is not None and seg.still_tolerance == TOL
    offline = StreamingSegmenter(seg.policy, seg.detector_config, seg.duration_model, seg.head)
    t0 = (int(time.time()) - 10_000) * 1_000_000_000
    inner = 0
    for i, ep in enumerate(_episodes("craft")):
        stream = received(ep)
        got, pis = live(node, stream, t0 + i * 10 * 1_000_000_000)
        replay = replay_episode(offline, stream, include_done_step=True)
        want = [(b.step, b.subtask, b.detected_at, f"{np.float32(b.score):.6f}") for b in replay.published]
        assert got == want  # the message carries the score as float32
        assert replay.run_ends is not None and len(replay.run_ends) < stream.length  # pauses were not stepped
        np.testing.assert_allclose(pis[:len(replay.run_ends), -1], replay.pi_end[replay.run_ends], atol=1e-6)
        inner += sum(not b.final for b in replay.published)
    assert inner > 3 and node.counters()["still_observations"] > 0
    node.destroy_node()


def test_an_episode_the_idle_rule_ends_closes_on_the_streams_rows(ckpt: Path) -> None:
    ep, moved = paused_episode()
    held = np.repeat(ep.observations[-1:], 40, axis=0)  # the robot waits 1.6 s: the idle rule ends it
    obs = np.concatenate([ep.observations, held, paused_episode(seed=12)[0].observations])
    stamps = [100 * 10**9 + 40 * MS * t for t in range(len(obs))]
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DETECTOR)
    record = replay_stream(seg, obs, stamps, StreamLimits(idle_s=1.0, idle_speed=0.01))
    first = [event for episode, _, event in record.boundaries if episode == 1]
    stepped = [out.step_index for episode, _, out in record.steps if episode == 1]
    # the idle rule trims the stream's first row (still before any motion), so the episode's rows start one
    # later; it ends at the first held row, its final observation (row T = 60): the last real step is 59
    assert stepped == [0, *[t - 1 for t in moved[1:]], ep.length - 1]
    assert len(first) > 2 and first[-1].final and first[-1].step == ep.length - 1
    assert all(event.step + 1 in stepped for event in first[:-1])  # each at the last row of a run
