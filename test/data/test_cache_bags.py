"""Per-bag cache entries (``data.cache_workers``): built over worker processes, the same episodes as the
single-entry cache, and adding bags parses only the new ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from batch_bags import SPEC, write_lab_bag

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.cache import EpisodeArrays, load_arrays
from ompn_ros.data.reader import final_row_guessed


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("lab_bags")
    for i in range(6):
        write_lab_bag(root / f"day{i}", 20 + i, episodes=2, steps=24)
    return root


def _same(a: EpisodeArrays, b: EpisodeArrays) -> None:
    assert len(a) == len(b)
    for x, y in zip(a.episodes(), b.episodes(), strict=True):
        np.testing.assert_array_equal(x.observations, y.observations)
        np.testing.assert_array_equal(x.actions, y.actions)
        np.testing.assert_array_equal(x.subtask, y.subtask)
        np.testing.assert_array_equal(x.extras["subtask_id"], y.extras["subtask_id"])
        assert (x.task, x.seed) == (y.task, y.seed)


def test_parallel_per_bag_entries_hold_the_same_episodes(bags: Path, tmp_path: Path) -> None:
    spec = ReaderSpec.from_dict(SPEC)
    serial = load_arrays(bags, spec=spec, cache_dir=tmp_path / "one")
    two = load_arrays(bags, spec=spec, cache_dir=tmp_path / "two", workers=2)
    _same(serial, two)
    assert len(list((tmp_path / "two" / "bags").iterdir())) == 6
    assert two.report.startswith("read 6 bag(s) through per-bag cache entries: 12 episode(s)")
    assert final_row_guessed(two.facts) == final_row_guessed(serial.facts)
    assert two.facts == serial.facts and len(two.facts) == 6
    again = load_arrays(bags, spec=spec, cache_dir=tmp_path / "two", workers=2)
    assert again.cache_hit and again.cache_path == two.cache_path


def test_adding_bags_parses_only_the_new_ones(bags: Path, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    spec = ReaderSpec.from_dict(SPEC)
    parsed: list[str] = []
    read = read_episodes

    def counting(paths, **kw):  # type: ignore[no-untyped-def]
        parsed.extend(str(Path(p).name) for p in paths)
        return read(paths, **kw)

    monkeypatch.setattr("ompn_ros.data.cache.build.read_episodes", counting)  # the parse the cache runs
    first = sorted(bags.iterdir())[:4]
    load_arrays(first, spec=spec, cache_dir=tmp_path, workers=1)
    assert parsed == ["day0", "day1", "day2", "day3"]
    parsed.clear()
    grown = load_arrays(sorted(bags.iterdir()), spec=spec, cache_dir=tmp_path, workers=1)
    assert parsed == ["day4", "day5"] and not grown.cache_hit
    _same(grown, load_arrays(bags, spec=spec, cache_dir=tmp_path / "single"))


def test_ompn_train_reads_through_per_bag_entries(bags: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from ompn_ros.app import training

    monkeypatch.setenv("OMPN_CACHE_DIR", str(tmp_path / "cache"))
    spec = tmp_path / "reader.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    data = training.bag_data([str(bags)], {"reader_spec": str(spec), "cache_workers": 1})
    assert len(data.episodes) == 12 and (tmp_path / "cache" / "bags").is_dir()
