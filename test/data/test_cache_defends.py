"""A cache entry defends itself: garbage values, NaN, another bag's entry under this key, an edited
offsets file are never trained on; the entry is rebuilt from the bags with a note.  Temporaries of a
killed run are removed by the next run, a running writer's never."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ompn_ros import layout
from ompn_ros.data.cache import EpisodeArrays, load_arrays
from ompn_ros.data.recorder.bag_writer import write_episodes
from ompn_ros.train import synthetic


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bags")
    out = {}
    for name, seed in (("a", 1), ("b", 2)):
        episodes = synthetic.make_dataset("discrete", 3, seed=seed)
        domain = dataclasses.replace(layout.CRAFT, obs_dim=episodes[0].observations.shape[1])
        write_episodes(root / name, episodes, domain)
        out[name] = root / name
    return out


def _entry(arrays: EpisodeArrays) -> Path:
    assert arrays.cache_path is not None
    return arrays.cache_path


def _poke(file: Path, value: float) -> None:
    """Overwrite one float32 in the data of an .npy file (its header untouched)."""
    data = np.load(file, mmap_mode="r+")
    data.flat[3] = value
    data.flush()
    del data


def _garbage(entry: Path, other: Path) -> None:
    _poke(entry / "observations.npy", 1234.5)


def _nan(entry: Path, other: Path) -> None:
    _poke(entry / "observations.npy", float("nan"))


def _other_bag(entry: Path, other: Path) -> None:
    shutil.rmtree(entry)
    shutil.copytree(other, entry)


def _offsets(entry: Path, other: Path) -> None:
    offsets = np.load(entry / "obs_offsets.npy")
    offsets[1] += 5  # a valid .npy of the right dtype and shape, cutting the episodes wrongly
    np.save(entry / "obs_offsets.npy", offsets)


def _offsets_and_checksum(entry: Path, other: Path) -> None:
    """Edited by hand, the index's checksum recomputed too: the offsets rule still catches it."""
    from ompn_ros.data.cache import file_digest

    _offsets(entry, other)
    index = json.loads((entry / "index.json").read_text())
    index["arrays"]["obs_offsets"]["blake2b"] = file_digest(entry / "obs_offsets.npy")
    (entry / "index.json").write_text(json.dumps(index))


def _torn_offsets(entry: Path, other: Path) -> None:
    (entry / "act_offsets.npy").write_bytes(b"\x93NUMPY garbage")


SPOIL: dict[str, tuple[Callable[[Path, Path], None], str]] = {
    "garbage": (_garbage, "checksum"),
    "nan": (_nan, "checksum"),
    "other_bag": (_other_bag, "other bags or settings"),
    "offsets": (_offsets, "checksum"),
    "offsets_and_checksum": (_offsets_and_checksum, "whole episodes"),
    "torn_offsets": (_torn_offsets, "checksum"),
}


@pytest.mark.parametrize("kind", sorted(SPOIL))
def test_a_spoiled_entry_is_rebuilt_with_a_note(bags: dict[str, Path], tmp_path: Path, kind: str) -> None:
    cache = tmp_path / "cache"
    first = load_arrays(bags["a"], cache_dir=cache)
    want = np.array(first.observations)
    other = _entry(load_arrays(bags["b"], cache_dir=cache))
    spoil, words = SPOIL[kind]
    entry = _entry(first)
    del first
    spoil(entry, other)
    again = load_arrays(bags["a"], cache_dir=cache)
    assert not again.cache_hit
    np.testing.assert_array_equal(np.asarray(again.observations), want)
    assert len(again.notes) == 1 and words in again.notes[0] and str(entry) in again.notes[0], again.notes
    assert again.notes[0] in again.report
    third = load_arrays(bags["a"], cache_dir=cache)  # the rebuilt entry is a plain hit
    assert third.cache_hit and not third.notes


def test_a_spoiled_per_bag_entry_is_rebuilt_with_a_note(bags: dict[str, Path], tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    first = load_arrays([bags["a"], bags["b"]], cache_dir=cache, workers=1)
    want = np.array(first.observations)
    (bag_a,) = [p for p in (cache / "bags").iterdir() if p.name.startswith("bag_")][:1]
    _nan(bag_a, bag_a)
    del first
    again = load_arrays([bags["a"], bags["b"]], cache_dir=cache, workers=1)
    np.testing.assert_array_equal(np.asarray(again.observations), want)
    assert len(again.notes) == 1 and "checksum" in again.notes[0]


KILLED_WRITER = """
import os, signal, sys
from pathlib import Path
import numpy as np
from ompn_ros.data.cache import EntryWriter
writer = EntryWriter(Path(sys.argv[1]) / "episodes_0123")
writer._cols["observations"].append(np.zeros((4, 3), np.float32))
print("writing", flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_runs_temporaries_are_removed_by_the_next_run(bags: dict[str, Path], tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    done = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(cache)], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ))
    assert done.returncode == -signal.SIGKILL and "writing" in done.stdout, done.stderr
    left = [p for p in cache.iterdir() if p.name.startswith(".")]
    assert len(left) == 1 and left[0].is_dir()
    from ompn_ros.data.cache import EntryWriter

    running = EntryWriter(cache / "episodes_4567")  # a writer of this process, still at work
    load_arrays(bags["a"], cache_dir=cache)
    hidden = sorted(p.name for p in cache.iterdir() if p.name.startswith("."))
    assert hidden == [running.tmp.name], hidden
    running.abort()
