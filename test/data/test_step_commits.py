"""Commit points of a live recording: a recording killed after any commit ends with whole steps."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data.recorder.step_commits import COMMIT, STREAM_NS, StepCommits

TOPICS = ("obs", "action", "subtask")
STEP_NS = 1_000_000  # 1 kHz
Message = tuple[int, str, int]  # stamp, topic, step


def _published(steps: int, every: dict[str, int] | None = None) -> list[Message]:
    """In publish order: each step's observation, then its partners (``every``: a topic's step stride)."""
    stride = every or {}
    return [(k * STEP_NS + j * 10_000, topic, k) for k in range(steps) for j, topic in enumerate(TOPICS)
            if k % stride.get(topic, 1) == 0]


def _delivered(published: list[Message], rng: np.random.Generator) -> list[Message]:
    """The order a loaded recorder takes them in: an executor's wait cycles, each taking one message
    from every subscription that has one, in creation order (one DDS reader per topic, first in
    first out), 0.3 steps a cycle, and in 1 cycle of 200 a stall of up to 20 steps (the CPU taken by
    other processes) after which every reader holds a backlog."""
    queues = {t: [m for m in published if m[1] == t] for t in TOPICS}
    now, out = 0, []
    while any(queues.values()):
        if rng.random() < 0.005:
            now += int(rng.integers(1, 20)) * STEP_NS
        taken = False
        for topic in TOPICS:
            if queues[topic] and queues[topic][0][0] <= now:
                out.append(queues[topic].pop(0))
                taken = True
        now += 3 * STEP_NS // 10 if taken else STEP_NS // 10
    return out


def _record(rule: StepCommits[Message], messages: list[Message], period: int) -> list[list[Message]]:
    """The written messages at each commit ("time" advances one message a tick; the commit period is
    ``period`` messages)."""
    written: list[Message] = []
    snapshots, last = [], 0
    for i, msg in enumerate(messages):
        for action in rule.offer(msg[1], msg[0], msg, (i - last) / period * rule.period_s):
            if action is COMMIT:
                snapshots.append(list(written))
                last = i
            else:
                written.append(action)
    written.extend(rule.flush())
    assert sorted(written) == sorted(messages)  # nothing lost or repeated by holding
    return snapshots


def _whole(kept: list[Message], every: dict[str, int] | None = None) -> bool:
    """The kept messages are exactly the messages of whole steps (an observation and its partners)."""
    steps = {k for _, t, k in kept if t == "obs"}
    stride = every or {}
    want = {(t, k) for t in TOPICS for k in steps if k % stride.get(t, 1) == 0}
    return {(t, k) for _, t, k in kept} == want


@pytest.mark.parametrize("seed", range(20))
def test_every_commit_keeps_whole_steps_under_a_loaded_executor(seed: int) -> None:
    messages = _delivered(_published(400), np.random.default_rng(seed))
    rule: StepCommits[Message] = StepCommits("obs", period_s=1.0)
    snapshots = _record(rule, messages, period=30)
    assert len(snapshots) >= 30  # 1 200 messages, a period of 30: a commit every half period or so
    assert rule.forced == 0
    for kept in snapshots:
        assert _whole(kept), (seed, len(kept))


def test_without_the_hold_the_same_delivery_cuts_steps() -> None:
    """The control: committing right before the step opening (no hold) cuts steps under the same
    delivery, so the test above can fail."""
    broken = 0
    for seed in range(20):
        messages = _delivered(_published(400), np.random.default_rng(seed))
        last = 0
        for i, (_, topic, _) in enumerate(messages):
            if topic == "obs" and i - last >= 15:
                broken += not _whole(messages[:i])
                last = i
    assert broken > 0


def test_a_sparse_topic_is_waited_for_from_the_cut_on() -> None:
    every = {"subtask": 4}
    messages = _delivered(_published(300, every), np.random.default_rng(0))
    rule: StepCommits[Message] = StepCommits("obs", period_s=1.0)
    snapshots = _record(rule, messages, period=20)
    assert len(snapshots) >= 10
    for kept in snapshots:
        assert _whole(kept, every)


def test_a_silent_topic_is_not_waited_for_and_a_whole_period_forces_the_commit() -> None:
    rule: StepCommits[str] = StepCommits("obs", period_s=1.0)
    assert rule.offer("obs", 0, "o0", 0.0) == ["o0"]
    assert rule.offer("action", 10, "a0", 0.1) == ["a0"]
    assert rule.offer("obs", 20, "o1", 0.6) == []  # the cut: held until action delivers from it on
    assert rule.offer("action", 15, "a0b", 0.6) == ["a0b"]  # before the cut: completes step 0
    assert rule.due(0.9) == []
    assert rule.due(1.0) == [COMMIT, "o1"] and rule.forced == 1  # a whole period: made anyway
    late = 20 + STREAM_NS + 1
    assert rule.offer("obs", late, "o2", 0.6) == [COMMIT, "o2"]  # action silent: not waited for
    assert not rule.idle_commit(0.9) and rule.idle_commit(1.0)


def test_without_a_step_topic_and_bad_period() -> None:
    rule: StepCommits[str] = StepCommits(None, period_s=1.0)
    assert rule.offer("x", 5, "m", 0.4) == ["m"]
    assert rule.offer("y", 6, "n", 0.5) == [COMMIT, "n"]
    with pytest.raises(ValueError, match="period_s"):
        StepCommits("obs", 0.0)
