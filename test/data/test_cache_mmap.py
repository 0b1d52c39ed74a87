"""The memory-mapped cache entry: values round-trip, step arrays are read-only memmaps, stale ones rebuild."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros.data import ReaderSpec, load_arrays, read_episodes, write_episodes
from ompn_ros.data.cache import CACHE_FORMAT, INDEX, EntryWriter, EpisodeArrays, NpyAppender
from ompn_ros.data.errors import CacheFormatError, NpyAppendError


def _bags(tmp_path: Path) -> tuple[Path, list]:  # type: ignore[type-arg]
    episodes = make_episodes("dial", 5, seed=3)
    write_episodes(tmp_path / "bags" / "a", episodes[:2], "dial")
    write_episodes(tmp_path / "bags" / "b", episodes[2:], "dial")
    return tmp_path / "bags", episodes


def test_round_trip_through_mmap(tmp_path: Path) -> None:
    bags, episodes = _bags(tmp_path)
    arrays = load_arrays(bags, spec=ReaderSpec.for_domain("dial"), cache_dir=tmp_path / "cache")
    for name in ("observations", "actions", "subtask", "sketch"):
        arr = getattr(arrays, name)
        assert isinstance(arr, np.memmap) and not arr.flags.writeable, name
    assert isinstance(arrays.extras["joint_position"], np.memmap)
    memory = EpisodeArrays.from_episodes(episodes)
    for name in ("observations", "actions", "subtask", "sketch", "obs_offsets", "act_offsets", "seeds"):
        np.testing.assert_array_equal(getattr(arrays, name), getattr(memory, name), err_msg=name)
    assert arrays.observations.dtype == np.float32
    for a, b in zip(episodes, arrays.episodes()):
        assert_same_episode(a, b)
        assert np.shares_memory(b.observations, arrays.observations)  # a view, not a copy
        with pytest.raises(ValueError):
            b.observations[0, 0] = 1.0  # read-only: training cannot alter the cache


def test_in_memory_path_matches_the_cache(tmp_path: Path) -> None:
    bags, _ = _bags(tmp_path)
    spec = ReaderSpec.for_domain("dial")
    mapped = load_arrays(bags, spec=spec, cache_dir=tmp_path / "cache")
    memory = load_arrays(bags, spec=spec, use_cache=False)
    assert memory.cache_path is None and not isinstance(memory.observations, np.memmap)
    assert mapped.report == memory.report
    for a, b in zip(memory.episodes(), mapped.episodes()):
        assert_same_episode(a, b)


def test_a_stale_format_is_rebuilt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    bags, episodes = _bags(tmp_path)
    spec = ReaderSpec.for_domain("dial")
    first = load_arrays(bags, spec=spec, cache_dir=tmp_path / "cache")
    assert first.cache_path is not None
    index = first.cache_path / INDEX
    meta = json.loads(index.read_text())
    meta["format"] = CACHE_FORMAT - 1
    index.write_text(json.dumps(meta))
    with pytest.raises(CacheFormatError, match="format"):
        EpisodeArrays.load(first.cache_path)
    calls = {"n": 0}
    real = read_episodes

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr("ompn_ros.data.cache.build.read_episodes", counting)  # the parse the cache runs
    again = load_arrays(bags, spec=spec, cache_dir=tmp_path / "cache")
    assert not again.cache_hit and calls["n"] == 2
    assert json.loads(index.read_text())["format"] == CACHE_FORMAT
    for a, b in zip(episodes, again.episodes()):
        assert_same_episode(a, b)
    assert load_arrays(bags, spec=spec, cache_dir=tmp_path / "cache").cache_hit


def test_extras_kept_only_when_every_episode_has_them(tmp_path: Path) -> None:
    episodes = make_episodes("dial", 3, seed=5)
    del episodes[1].extras["joint_velocity"]
    writer = EntryWriter(tmp_path / "entry")
    writer.add(episodes[:2])
    writer.add(episodes[2:])
    writer.finish("report")
    loaded = EpisodeArrays.load(tmp_path / "entry")
    expected = EpisodeArrays.from_episodes(episodes)
    assert set(loaded.extras) == set(expected.extras) and "joint_velocity" not in loaded.extras
    assert not (tmp_path / "entry" / "extras__joint_velocity.npy").exists()
    assert loaded.report == "report" and not list(tmp_path.glob(".tmp_*"))


def test_a_bag_with_other_observation_sizes_is_named(tmp_path: Path) -> None:
    write_episodes(tmp_path / "bags" / "a", make_episodes("craft", 2, seed=1), "craft")
    write_episodes(tmp_path / "bags" / "b", make_episodes("dial", 2, seed=1), "dial")
    with pytest.raises(ValueError, match=r"bag .*b does not fit the bags before it"):
        load_arrays(tmp_path / "bags", cache_dir=tmp_path / "cache")
    assert not list((tmp_path / "cache").iterdir())  # no half-written entry left behind


def test_npy_appender_writes_a_standard_file(tmp_path: Path) -> None:
    out = NpyAppender(tmp_path / "x.npy")
    blocks = [np.arange(6, dtype=np.float32).reshape(2, 3), np.ones((0, 3), np.float32),
              np.full((1, 3), 7, np.float32)]
    for block in blocks:
        out.append(block)
    assert out.close() == (3, 3)
    np.testing.assert_array_equal(np.load(tmp_path / "x.npy"), np.concatenate(blocks))
    assert isinstance(np.load(tmp_path / "x.npy", mmap_mode="r"), np.memmap)
    bad = NpyAppender(tmp_path / "y.npy", np.int64, ())
    with pytest.raises(NpyAppendError, match="float64 rows after int64"):
        bad.append(np.zeros(2))
    bad.abort()
    assert not (tmp_path / "y.npy").exists()
    empty = NpyAppender(tmp_path / "z.npy", np.int64, ())
    assert empty.close() == (0,) and np.load(tmp_path / "z.npy").shape == (0,)


def test_obs_names_survive_the_cache(tmp_path: Path) -> None:
    from joint_lab_bags import SPEC_DICT, write_lab_bag

    write_lab_bag(tmp_path / "bag")
    spec = ReaderSpec.from_dict(SPEC_DICT)
    names = read_episodes(tmp_path / "bag", spec=spec).episodes[0].extras["obs_names"]
    assert len(names) == 14
    for use_cache in (True, False):
        arrays = load_arrays(tmp_path / "bag", spec=spec, cache_dir=tmp_path / "cache", use_cache=use_cache)
        assert arrays.obs_names == tuple(names)
        assert all(e.extras["obs_names"] == names for e in arrays.episodes())
    hit = load_arrays(tmp_path / "bag", spec=spec, cache_dir=tmp_path / "cache")
    assert hit.cache_hit and hit.obs_names == tuple(names)
    assert "obs_names" not in load_arrays(_bags(tmp_path)[0], spec=ReaderSpec.for_domain("dial"),
                                          cache_dir=tmp_path / "cache").episodes()[0].extras


def test_obs_names_kept_only_when_every_episode_agrees(tmp_path: Path) -> None:
    episodes = make_episodes("dial", 3, seed=2)
    dim = episodes[0].observations.shape[1]
    for ep in episodes:
        ep.extras["obs_names"] = [f"x{i}" for i in range(dim)]
    writer = EntryWriter(tmp_path / "same")
    writer.add(episodes)
    writer.finish("")
    assert EpisodeArrays.load(tmp_path / "same").obs_names == tuple(f"x{i}" for i in range(dim))
    episodes[2].extras["obs_names"] = [f"y{i}" for i in range(dim)]
    writer = EntryWriter(tmp_path / "mixed")
    writer.add(episodes)
    writer.finish("")
    assert EpisodeArrays.load(tmp_path / "mixed").obs_names == ()
    assert EpisodeArrays.from_episodes(episodes).obs_names == ()


def test_entries_of_another_format_are_pruned(tmp_path: Path) -> None:
    bags, _ = _bags(tmp_path)
    old = tmp_path / "cache" / "episodes_old"
    old.mkdir(parents=True)
    (old / INDEX).write_text(json.dumps({"format": CACHE_FORMAT - 1, "arrays": {}}))
    foreign = tmp_path / "cache" / "episodes_unknown"
    foreign.mkdir()  # no index: not an entry this cache judges
    load_arrays(bags, spec=ReaderSpec.for_domain("dial"), cache_dir=tmp_path / "cache")
    assert not old.exists() and foreign.exists()
