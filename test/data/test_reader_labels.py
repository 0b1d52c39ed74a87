"""Labels as another lab has them: skill ids, ordinals or boundary events, other topic names,
no markers (pauses separate episodes), and bad input named clearly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from label_bags import SKILL_IDS, _ordinals, _spec, _write_lab_bag

from ompn_ros.data import MissingTopicError, ReaderSpec, read_episodes
from ompn_ros.data.errors import AlignmentError, LabelError, NoEpisodeError
from ompn_ros.metrics import alignment_accuracy, mean_f1


def test_every_label_kind_gives_the_same_ordinals_and_metrics(tmp_path: Path) -> None:
    results = {}
    for kind in ("id", "ordinal", "boundary"):
        truth = _write_lab_bag(tmp_path / kind, kind)
        result = read_episodes(tmp_path / kind, spec=_spec(kind))
        assert len(result.episodes) == 3 and result.report.bags[0].split == "time_gap"
        for want, got in zip(truth, result.episodes):
            np.testing.assert_array_equal(got.observations, want["obs"])
            np.testing.assert_array_equal(got.actions, want["act"])
            np.testing.assert_array_equal(got.subtask, _ordinals(want["ids"]))
        results[kind] = result.episodes
    ids = [e.extras["subtask_id"].tolist() for e in results["id"]]
    assert ids == SKILL_IDS  # the user's ids are kept
    pred = [np.asarray([1, e.length - 1]) for e in results["id"]]  # any fixed prediction
    scores = {kind: (mean_f1(pred, [e.boundaries for e in eps], tol=1).f1,
                     alignment_accuracy(pred, [e.subtask for e in eps]))
              for kind, eps in results.items()}
    assert scores["id"] == scores["ordinal"] == scores["boundary"]
    assert [e.boundaries.tolist() for e in results["boundary"]] == [[1, 4, 6], [1, 3, 5], [2, 4, 7]]


def test_ids_read_as_ordinals_is_a_clear_error(tmp_path: Path) -> None:
    _write_lab_bag(tmp_path / "bag", "id")
    with pytest.raises(LabelError) as info:
        read_episodes(tmp_path / "bag", spec=_spec("ordinal"))
    text = str(info.value)
    assert info.value.topic == "/lab7/skill" and "episode #0" in text and "labels: id" in text
    assert "17, 17, 4" in text
    with pytest.raises(LabelError, match="labels: id"):  # the default (ordinal when present) too
        auto = ReaderSpec.from_dict({**_spec("ordinal").to_dict(), "labels": None})
        read_episodes(tmp_path / "bag", spec=auto)


def test_per_step_topic_read_as_boundary_events_is_a_clear_error(tmp_path: Path) -> None:
    _write_lab_bag(tmp_path / "bag", "id")
    spec = ReaderSpec.from_dict({**_spec("boundary").to_dict(), "subtask": "skill"})
    with pytest.raises(LabelError, match="every step carries a boundary event") as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert info.value.topic == "/lab7/skill"


def test_named_label_topic_missing(tmp_path: Path) -> None:
    _write_lab_bag(tmp_path / "bag", "id")
    spec = ReaderSpec.from_dict({**_spec("id").to_dict(), "subtask": "skill_label"})
    with pytest.raises(MissingTopicError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert info.value.topic == "/lab7/skill_label" and str(tmp_path / "bag") in str(info.value)
    assert read_episodes(tmp_path / "bag", spec=_spec("none")).episodes[0].subtask is None


def test_split_by_a_named_topic(tmp_path: Path) -> None:
    truth = _write_lab_bag(tmp_path / "bag", "id", reset_topic=True, pause_ns=0)
    gaps = read_episodes(tmp_path / "bag", spec=_spec("id", strict=False))
    assert len(gaps.episodes) == 1  # no pauses: the gap rule sees one long episode
    assert gaps.report.bags[0].dropped_steps == 2  # the final observations in the middle of it
    result = read_episodes(tmp_path / "bag", spec=_spec("id", split="topic", split_topic="reset"))
    assert result.report.bags[0].split == "topic" and len(result.episodes) == 3
    for want, got in zip(truth, result.episodes):
        np.testing.assert_array_equal(got.observations, want["obs"])
        assert got.extras["subtask_id"].tolist() == want["ids"]


def test_split_settings_are_checked(tmp_path: Path) -> None:
    from ompn_ros.data import ReaderSpecError

    with pytest.raises(ReaderSpecError, match="split_topic"):
        _spec("id", split="topic")
    with pytest.raises(ReaderSpecError, match="labels must be one of"):
        _spec("skills")
    _write_lab_bag(tmp_path / "bag", "id")
    with pytest.raises(MissingTopicError) as info:  # markers demanded, no episode topic in the bag
        read_episodes(tmp_path / "bag", spec=_spec("id", split="markers", episode="episode"))
    assert info.value.topic == "/lab7/episode"


@pytest.mark.parametrize("final", ["drop_last_step", "duplicate", "require"])
def test_episodes_without_the_post_final_observation(tmp_path: Path, final: str) -> None:
    truth = _write_lab_bag(tmp_path / "bag", "id", final_obs=False)
    spec = _spec("id", final_observation=final)
    if final == "require":
        with pytest.raises(AlignmentError, match="no observation after its last action") as info:
            read_episodes(tmp_path / "bag", spec=spec)
        assert info.value.topic == "/lab7/cam/features" and info.value.index == len(SKILL_IDS[0]) - 1
        loose = ReaderSpec.from_dict({**spec.to_dict(), "strict": False})
        with pytest.raises(NoEpisodeError, match="no final observation"):
            read_episodes(tmp_path / "bag", spec=loose)
        return
    result = read_episodes(tmp_path / "bag", spec=spec)
    report = result.report.bags[0]
    assert len(result.episodes) == 3 and list(report.adjusted.values()) == [[0, 1, 2]]
    for want, got in zip(truth, result.episodes):
        n = len(want["ids"])
        if final == "drop_last_step":  # every kept (observation, action) pair was recorded
            np.testing.assert_array_equal(got.observations, want["obs"])
            np.testing.assert_array_equal(got.actions, want["act"][: n - 1])
            assert got.subtask.tolist() == _ordinals(want["ids"])[: n - 1]
        else:
            np.testing.assert_array_equal(got.observations[:n], want["obs"])
            np.testing.assert_array_equal(got.observations[n], want["obs"][n - 1])
            np.testing.assert_array_equal(got.actions, want["act"])
    assert ("duplicated" in result.report.summary()) == (final == "duplicate")
