"""How whole episodes end on ``~/boundary`` (docs/design.md#episode-end), on what the node publishes
for the episodes of both sims, expert and human-like, with the shipped checkpoints and their own
detectors: one event per subtask, numbered 0, 1, ... without a repeat, one ``final`` event last; and
the number of subtasks reported is the true number whenever the detector found every true boundary
and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import Episode
from ompn_ros.detect.online import BoundaryEvent, subtask_ends
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.stream.replay import replay_episode
from sim_nodes import derive_seed
from sim_nodes.human import parse_human
from sim_nodes.registry import default_tasks, expert_episode


def _episodes(domain: str) -> list[Episode]:
    tasks = default_tasks(domain)
    # Dial 30000..30003: the last press decided 4, 0, 0 and 1 steps before the end (before: a fifth
    # subtask of 1 step, the last boundary repeated twice, a fifth subtask of 1 step)
    experts = [expert_episode(domain, 30000 + i, task=tasks[i % len(tasks)]) for i in range(4)]
    human = parse_human(domain, ())
    if domain == "craft":
        from sim_nodes.craft.human import generate_human_episode as craft_human

        people = [craft_human(derive_seed(9, i), human, task=tasks[i % len(tasks)]) for i in range(3)]
    else:
        from sim_nodes.dial.human import generate_human_episode as dial_human

        people = [dial_human(derive_seed(9, i), human) for i in range(2)]
    return experts + people


def _all_found(ends: list[BoundaryEvent], truth: np.ndarray) -> bool:
    """Every true boundary has a subtask end within a step and every subtask end a true boundary (the
    metrics' tolerance of 1)."""
    return (all(any(abs(e.step - int(g)) <= 1 for e in ends) for g in truth)
            and all(any(abs(e.step - int(g)) <= 1 for g in truth) for e in ends))


@pytest.mark.parametrize("domain", ["dial", "craft"])
def test_one_event_per_subtask_and_the_true_count(domain: str) -> None:
    checkpoint = shipped_checkpoint(domain)
    settings = load_detector_settings(checkpoint)
    policy = stepper_from_checkpoint(str(checkpoint), "jit", "cpu")
    segmenter = StreamingSegmenter(policy, settings.online, settings.duration_model, settings.head)
    counted = 0
    for ep in _episodes(domain):
        published = replay_episode(segmenter, ep, include_done_step=True).published
        ends = subtask_ends(published)
        assert [e.subtask for e in ends] == list(range(len(ends))), published  # no repeat, no gap
        assert [e.final for e in published] == [False] * (len(published) - 1) + [True], published
        assert len(published) - len(ends) <= 1 and (published[-1] in ends or published[-1].episode_end)
        if published[-1].episode_end:  # it reports the count, at the episode's last step
            assert published[-1].subtask == len(ends) and published[-1].step == ep.length - 1
        if _all_found(ends, ep.boundaries):
            assert len(ends) == len(ep.boundaries), (ep.seed, ep.boundaries.tolist(), published)
            counted += 1
    assert counted >= 3  # most of these episodes are found whole
