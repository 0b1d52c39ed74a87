"""Decoding while reading (``reader.columns``): the episodes are bit-identical to the batch decoder's
(the step topic kept raw and decoded afterwards) and to what was written, for mcap and sqlite3,
markers and gaps, every label kind, a missing final observation, several observation topics, and
bags with bad messages (the column falls back to raw bytes; a cut bag is assembled again)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from assembled_bags import _assemble_bag
from bad_messages import _bag_with_bad_messages
from joint_lab_bags import SPEC_DICT
from label_bags import _ordinals, _spec, _write_lab_bag
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import BagError
from ompn_ros.data.obs import assemble_stream
from ompn_ros.data.reader import iter_raw_messages, observe
from ompn_ros.data.reader import read as read_module
from ompn_ros.data.reader.columns import Float32Column
from ompn_ros.data.reader.read import read_raw
from ompn_ros.data.reader.verify import nonfinite_rows
from ompn_ros.data.recorder.bag_writer import EpisodeBagWriter

MS = 1_000_000


def _batch(monkeypatch: pytest.MonkeyPatch, path: Path, spec: ReaderSpec, on_error: Any = "raise") -> Any:
    """The reader with nothing decoded while reading (every topic kept raw)."""
    with monkeypatch.context() as patch:
        patch.setattr(read_module, "stream_plan", lambda *args: None)
        return read_episodes(path, spec=spec, on_error=on_error)


def _identical(a: Any, b: Any) -> None:
    """Same episodes, bit for bit (values, dtypes, extras) and the same report."""
    assert len(a.episodes) == len(b.episodes)
    for x, y in zip(a.episodes, b.episodes):
        for name in ("observations", "actions", "subtask", "sketch"):
            u, v = getattr(x, name), getattr(y, name)
            assert (u is None) == (v is None), name
            if u is not None:
                assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes(), name
        assert (x.task, x.seed, x.success) == (y.task, y.seed, y.success)
        assert sorted(x.extras) == sorted(y.extras)
        for key, value in x.extras.items():
            assert np.array_equal(np.asarray(value), np.asarray(y.extras[key])), key
    assert a.report.summary() == b.report.summary()
    assert a.report.to_dict() == b.report.to_dict()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_craft_bag_decoded_while_read(tmp_path: Path, storage: str, monkeypatch: pytest.MonkeyPatch) -> None:
    episodes = make_episodes("craft", 5, seed=3, min_steps=4, max_steps=12)
    with EpisodeBagWriter(tmp_path / "bag", layout.CRAFT, storage=storage) as writer:
        for ep in episodes:
            writer.write_episode(ep)
    spec = ReaderSpec.for_domain("craft")
    raw = read_raw(tmp_path / "bag", spec, "raise")
    obs = raw.topics["/" + layout.OBSERVATION]
    assert obs.column is not None and obs.raws == [] and obs.column.n == sum(e.length + 1 for e in episodes)
    result = read_episodes(tmp_path / "bag", spec=spec)
    for want, got in zip(episodes, result.episodes, strict=True):
        assert_same_episode(want, got)
    bases = [e.observations.base for e in result.episodes]
    assert bases[0] is not None and all(b is bases[0] for b in bases)  # views of one array, no copies
    _identical(result, _batch(monkeypatch, tmp_path / "bag", spec))


@pytest.mark.parametrize("kind", ["id", "ordinal", "boundary"])
@pytest.mark.parametrize("final", ["present", "drop_last_step", "duplicate"])
def test_label_kinds_and_final_observation(tmp_path: Path, kind: str, final: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    truth = _write_lab_bag(tmp_path / "bag", kind, final_obs=final == "present")
    spec = _spec(kind, final_observation="drop_last_step" if final == "present" else final)
    assert read_raw(tmp_path / "bag", spec, "raise").topics["/lab7/cam/features"].column is not None
    result = read_episodes(tmp_path / "bag", spec=spec)
    assert len(result.episodes) == 3
    for want, got in zip(truth, result.episodes):
        n = len(want["ids"]) - (final == "drop_last_step")
        obs = want["obs"]
        rows = np.concatenate([obs, obs[-1:]]) if final == "duplicate" else obs[: n + 1]
        np.testing.assert_array_equal(got.observations, rows)
        np.testing.assert_array_equal(got.actions, want["act"][:n])
        np.testing.assert_array_equal(got.subtask, _ordinals(want["ids"])[:n])
    _identical(result, _batch(monkeypatch, tmp_path / "bag", spec))


@pytest.mark.parametrize("bad", [{layout.OBSERVATION: 17, layout.ACTION: 8}, {layout.OBSERVATION: 9},
                                 {layout.OBSERVATION: 0}, {layout.ACTION: 20}])
def test_bad_messages_give_the_batch_decoder_result(tmp_path: Path, bad: dict[str, int],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    _bag_with_bad_messages(tmp_path / "bag", bad)
    spec = ReaderSpec.for_domain("craft")
    _identical(read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail"),
               _batch(monkeypatch, tmp_path / "bag", spec, "skip_tail"))
    errors = []
    for read in (lambda: read_episodes(tmp_path / "bag", spec=spec),
                 lambda: _batch(monkeypatch, tmp_path / "bag", spec)):
        with pytest.raises(BagError) as info:
            read()
        errors.append((type(info.value), str(info.value)))
    assert errors[0] == errors[1]


def test_assembled_while_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _assemble_bag(tmp_path / "bag")
    spec = ReaderSpec.from_dict(SPEC_DICT)
    raw = read_raw(tmp_path / "bag", spec, "raise")
    assert raw.assembly is not None and raw.assembly.n == len(raw.topics["/lab/arm/joint_states"].stamps)
    fed = ("/lab/arm/joint_states", "/lab/arm/gripper", "/lab/arm/ft")
    assert not any(raw.topics[t].has_raws for t in fed)
    with monkeypatch.context() as patch:  # the rows built while reading are used: no second read
        patch.setattr(observe, "reread", lambda *args: pytest.fail("the bag was read twice"))
        result = read_episodes(tmp_path / "bag", spec=spec)
    stream = assemble_stream(iter_raw_messages(tmp_path / "bag"), spec.assemble.with_namespace("/lab"))  # type: ignore[union-attr]
    rows = np.concatenate([e.observations for e in result.episodes])
    assert rows.tobytes() == stream.observations.tobytes()
    assert result.report.bags[0].obs_dropped == {"stale": 1, "wrong_size": 1}
    _identical(result, _batch(monkeypatch, tmp_path / "bag", spec))


def test_cut_bag_is_assembled_again_from_storage(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _assemble_bag(tmp_path / "bag", bad_command=30)  # in the second episode
    spec = ReaderSpec.from_dict(SPEC_DICT)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert len(result.episodes) == 1 and "/lab/arm/command" in (result.report.bags[0].error or "")
    _identical(result, _batch(monkeypatch, tmp_path / "bag", spec, "skip_tail"))


def test_column_gives_back_the_exact_bytes_and_grows() -> None:
    rng = np.random.default_rng(0)
    rows = rng.standard_normal((7, 5)).astype(np.float32)
    rows[2, 1] = np.nan
    raws = [m.serialize(m.float32_array(r, "obs")) for r in rows]
    col = Float32Column(None, capacity=2)  # the index undercounts: the array grows
    assert all(col.add(r) for r in raws)
    assert col.values.tobytes() == rows.tobytes() and col.to_raws() == raws
    assert not col.add(m.serialize(m.float32_array(np.zeros(6, np.float32), "obs")))  # another length
    assert not Float32Column(4, 10).add(raws[0])  # the spec says 4 elements
    col.take(np.asarray([3, 1]))
    assert col.values.tobytes() == rows[[3, 1]].tobytes()


def test_nonfinite_rows_in_blocks() -> None:
    values = np.ones((1000, 7), np.float32)
    values[[0, 333, 334, 999], [1, 0, 6, 3]] = [np.inf, np.nan, -np.inf, np.nan]
    expected = np.flatnonzero(~np.isfinite(values).all(axis=1))
    for block in (1, 28, 100, 1 << 22):
        np.testing.assert_array_equal(nonfinite_rows(values, block), expected)
    assert nonfinite_rows(np.zeros((3, 2), np.int64)).size == 0


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("bad", [None, 0, 11])
def test_float32_commands_decoded_while_read(tmp_path: Path, storage: str, bad: int | None,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Another lab's ``Float32MultiArray`` command topic is a column too (its bytes are never held
    beside their rows: the reader's peak memory); a command of another length (``bad``: its index)
    ends the column and gives the batch decoder's error on the same message."""
    from compat_corpus import CMD, SPEC, check_episodes, demos, write_rosbags

    demo = demos([12, 9, 14], seed=31)
    if bad is not None:
        at = [i for i, x in enumerate(demo.messages) if x[1] == CMD][bad]
        stamp, topic, _ = demo.messages[at]
        demo.messages[at] = (stamp, topic, m.serialize(m.float32_array(np.zeros(5, np.float32), "cmd")))
    bag = write_rosbags(tmp_path / "bag", demo, storage=storage)
    raw = read_raw(bag, SPEC, "raise")
    column = raw.topics[CMD].column
    if bad is None:
        assert column is not None and raw.topics[CMD].raws == []
        assert column.n == sum(len(a) for a in demo.actions)
        result = read_episodes(bag, spec=SPEC)
        check_episodes(result.episodes, demo)
        bases = [ep.actions.base for ep in result.episodes]
        assert bases[0] is not None and all(b is bases[0] for b in bases)  # views of one array, no copies
        _identical(result, _batch(monkeypatch, bag, SPEC))
        return
    assert column is None and len(raw.topics[CMD].raws) == sum(len(a) for a in demo.actions)
    errors = []
    for read in (lambda: read_episodes(bag, spec=SPEC), lambda: _batch(monkeypatch, bag, SPEC)):
        with pytest.raises(BagError) as info:
            read()
        errors.append((type(info.value), str(info.value)))
    assert errors[0] == errors[1] and f"message #{bad}" in errors[0][1], errors
    skipped = read_episodes(bag, spec=SPEC, on_error="skip_tail")
    _identical(skipped, _batch(monkeypatch, bag, SPEC, "skip_tail"))
