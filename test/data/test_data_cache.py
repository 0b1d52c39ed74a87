"""On-disk cache of parsed bags: hits on identical bytes, misses on changed content."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros.data import ReaderSpec, load_arrays, read_episodes, write_episodes
from ompn_ros.data import cache as cache_mod
from ompn_ros.data.recorder.storage import refresh_chunk_crcs


def test_cache_hit_and_content_miss(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    episodes = make_episodes("dial", 5, seed=9)
    write_episodes(tmp_path / "bags" / "p0", episodes[:3], "dial")
    write_episodes(tmp_path / "bags" / "p1", episodes[3:], "dial", storage="sqlite3")
    spec = ReaderSpec.for_domain("dial")
    cache_dir = tmp_path / "cache"

    first = load_arrays(tmp_path / "bags", spec=spec, cache_dir=cache_dir)
    assert not first.cache_hit and first.cache_path is not None and first.cache_path.is_dir()
    assert len(first) == 5
    np.testing.assert_array_equal(first.obs_offsets, np.cumsum([0] + [e.length + 1 for e in episodes]))
    for a, b in zip(episodes, first.episodes()):
        assert_same_episode(a, b)

    calls = {"n": 0}
    real = read_episodes

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr("ompn_ros.data.cache.build.read_episodes", counting)  # the parse the cache runs
    second = load_arrays(tmp_path / "bags", spec=spec, cache_dir=cache_dir)
    assert second.cache_hit and calls["n"] == 0 and second.key == first.key
    assert second.report == first.report and "5 episode(s)" in second.report
    for a, b in zip(episodes, second.episodes()):
        assert_same_episode(a, b)
    np.testing.assert_array_equal(second.extras["joint_position"],
                                  np.concatenate([e.extras["joint_position"] for e in episodes]))

    # same size and mtime, different bytes: must miss
    file = next((tmp_path / "bags" / "p0").glob("*.mcap"))
    stat = file.stat()
    data = bytearray(file.read_bytes())
    needle = np.asarray(episodes[0].observations[0, :2], dtype="<f4").tobytes()
    at = data.find(needle)
    assert at > 0
    data[at:at + 4] = np.asarray([123.5], dtype="<f4").tobytes()
    file.write_bytes(bytes(data))
    refresh_chunk_crcs(file)  # a deliberate edit: the chunk CRCs would flag it as corruption
    os.utime(file, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    third = load_arrays(tmp_path / "bags", spec=spec, cache_dir=cache_dir)
    assert not third.cache_hit and calls["n"] == 2 and third.key != first.key  # one read per bag
    assert third.observations[0, 0] == np.float32(123.5)

    # another reader spec is another entry
    other = load_arrays(tmp_path / "bags", spec=ReaderSpec(), cache_dir=cache_dir)
    assert not other.cache_hit and "joint_position" not in other.extras


def test_cache_dir_from_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OMPN_CACHE_DIR", str(tmp_path / "envcache"))
    assert cache_mod.default_cache_dir() == tmp_path / "envcache"
    write_episodes(tmp_path / "bag", make_episodes("craft", 2, seed=10), "craft")
    arrays = load_arrays(tmp_path / "bag")
    assert arrays.cache_path is not None and arrays.cache_path.parent == tmp_path / "envcache"
    for file in arrays.cache_path.glob("*.npy"):  # plain arrays: loadable without pickle
        assert np.load(file, allow_pickle=False).dtype != object
    assert load_arrays(tmp_path / "bag").cache_hit


def test_cache_keeps_the_users_subtask_ids(tmp_path: Path) -> None:
    from ompn_ros.data.cache import EpisodeArrays

    episodes = make_episodes("craft", 3, seed=4)
    for i, ep in enumerate(episodes):
        assert ep.subtask is not None
        ep.extras["subtask_id"] = np.asarray([17, 4, 9])[ep.subtask] + i
    arrays = EpisodeArrays.from_episodes(episodes)
    arrays.save(tmp_path / "c")
    loaded = EpisodeArrays.load(tmp_path / "c")
    for a, b in zip(episodes, loaded.episodes()):
        np.testing.assert_array_equal(a.extras["subtask_id"], b.extras["subtask_id"])
        assert_same_episode(a, b)
