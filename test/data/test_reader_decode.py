"""The corrupt-tail cut: bad messages on several topics, the bag is cut once at the earliest."""

from __future__ import annotations

from pathlib import Path

from bad_messages import _bag_with_bad_messages
from synthetic_episodes import assert_same_episode

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.layout import JOINT_FIELDS


def test_cut_at_the_earliest_bad_message_of_any_topic(tmp_path: Path) -> None:
    # observation #17 is in episode 2; action #8 (step 2 of episode 1) comes earlier in time
    episodes = _bag_with_bad_messages(tmp_path / "bag", {layout.OBSERVATION: 17, layout.ACTION: 8})
    result = read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft"), on_error="skip_tail")
    assert len(result.episodes) == 1
    assert_same_episode(episodes[0], result.episodes[0])
    report = result.report.bags[0]
    assert report.error is not None and "'/action'" in report.error and "message #8" in report.error
    assert report.dropped_episodes == 1  # episode 1 lost its end marker with the tail


def test_later_bad_message_alone_keeps_more(tmp_path: Path) -> None:
    episodes = _bag_with_bad_messages(tmp_path / "bag", {layout.ACTION: 20})  # step 2 of episode 3
    result = read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft"), on_error="skip_tail")
    assert len(result.episodes) == 3
    for a, b in zip(episodes, result.episodes):
        assert_same_episode(a, b)


def test_joint_fields_have_one_definition() -> None:
    from ompn_ros.data.reader import joints, spec

    assert JOINT_FIELDS == ("position", "velocity", "effort")
    assert not hasattr(spec, "JOINT_FIELDS") and not hasattr(joints, "JOINT_FIELDS")
