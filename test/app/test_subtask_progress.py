"""examples/subtask_progress.py: one line per finished subtask and one per episode end, without
deduplication (the node publishes each subtask once and closes an episode with one ``final`` message);
fed the events of a whole replayed episode it counts the episode's subtasks; as a separate process it
reads SubtaskBoundary messages published here."""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

from node_process import NodeProcess

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "subtask_progress.py"


def _example():
    spec = importlib.util.spec_from_file_location("subtask_progress", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _boundary(episode: int, step: int, subtask: int, final: bool = False, **kw):
    fields = dict(node="/r1/ompn_node", episode=episode, step=step, subtask=subtask, subtask_id=-1,
                  score=0.5, decided_step=step + 1, final=final, kind=0)
    fields.update(kw)
    return SimpleNamespace(**fields)


def test_one_line_per_subtask_and_one_per_episode_end() -> None:
    progress = _example().Progress()
    lines = [line for msg in (
        _boundary(1, 4, 0, subtask_id=7), _boundary(1, 9, 1),
        _boundary(1, 11, 2, final=True, kind=1, score=0.0, decided_step=12),  # the episode end
        _boundary(2, 3, 0, final=True, decided_step=3),
    ) for line in progress.lines(msg)]  # fmt: skip
    assert lines == [
        "[/r1/ompn_node] episode 1: subtask 0 (id 7) done at step 4, score 0.50, decided 1 step later",
        "[/r1/ompn_node] episode 1: subtask 1 done at step 9, score 0.50, decided 1 step later",
        "[/r1/ompn_node] episode 1 finished: 2 subtasks, last step 11",
        "[/r1/ompn_node] episode 2: subtask 0 done at step 3, score 0.50, decided 0 steps later",
        "[/r1/ompn_node] episode 2 finished: 1 subtasks, last step 3",
    ]


def test_a_whole_dial_episode_reports_its_four_subtasks() -> None:
    """What the node publishes for a whole Dial episode (shipped checkpoint, its own detector) whose
    last press the detector decided a few steps before the episode ended: the example prints the
    episode's 4 subtasks, one line each, and "4 subtasks" (before: a 5th subtask of 1-4 steps, or
    the last one repeated)."""
    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.data.messages import SubtaskBoundary
    from ompn_ros.detect.settings import load_detector_settings
    from ompn_ros.model.load import stepper_from_checkpoint
    from ompn_ros.segmenter import StreamingSegmenter
    from ompn_ros.stream.replay import replay_episode
    from sim_nodes.registry import expert_episode

    checkpoint = shipped_checkpoint("dial")
    settings = load_detector_settings(checkpoint)
    segmenter = StreamingSegmenter(stepper_from_checkpoint(str(checkpoint), "jit", "cpu"), settings.online,
                                   settings.duration_model, settings.head)
    progress = _example().Progress()
    for seed in (30001, 30003):  # last press decided at the last step / 2 steps before the end
        episode = expert_episode("dial", seed)
        replay = replay_episode(segmenter, episode, include_done_step=True)
        messages = [SubtaskBoundary.from_event(e, node="/n", episode=1, sketch=episode.sketch)
                    for e in replay.published]
        lines = [line for msg in messages for line in progress.lines(msg)]
        assert len(episode.sketch) == 4 and len(lines) == 5, lines
        assert lines[-1].startswith("[/n] episode 1 finished: 4 subtasks"), lines
        assert [msg.subtask_id for msg in messages[:4]] == [int(i) for i in episode.sketch]


def test_the_example_node_reads_published_boundaries(ros_env: dict[str, str]) -> None:
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from ompn_interfaces.msg import SubtaskBoundary

    topic = f"/progress_{os.getpid()}/boundary"  # unique: the DDS domain may be shared
    proc = NodeProcess(ros_env, f"boundary_topic:={topic}", program=[sys.executable, str(EXAMPLE)])
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("progress_feeder", context=ctx)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = node.create_publisher(SubtaskBoundary, topic, qos)
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            proc.check()
            time.sleep(0.05)
        assert pub.get_subscription_count() == 1
        for step, subtask, final, kind in ((5, 0, False, 0), (12, 1, False, 0), (14, 2, True, 1)):
            msg = SubtaskBoundary(node="/r", episode=1, step=step, subtask=subtask, subtask_id=3 + subtask,
                                  score=0.75, decided_step=step + 2, final=final, kind=kind)
            pub.publish(msg)
        time.sleep(1.0)
    finally:
        rclpy.try_shutdown(context=ctx)
        out = proc.stop()
    assert out.splitlines()[-3:] == [
        "[/r] episode 1: subtask 0 (id 3) done at step 5, score 0.75, decided 2 steps later",
        "[/r] episode 1: subtask 1 (id 4) done at step 12, score 0.75, decided 2 steps later",
        "[/r] episode 1 finished: 2 subtasks, last step 14",
    ], out
    assert "Traceback" not in out
