"""The episode cache's key covers the ``.msg`` files of the reader spec's ``types:``: a lab's bag without
embedded definitions (a Humble-era sqlite3 bag, written with ``rosbags``) read through its package's
``.msg`` folder or its installed package; a definition edited between two builds (a field renamed or
retyped) is never served from the entry built with the old one."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import type_corpus as tc
from compat_corpus import edit_metadata, old_metadata, old_sqlite_schema, storage_file

from ompn_ros.data import ReaderSpec
from ompn_ros.data.cache import load_arrays
from ompn_ros.data.errors import CorruptBagError, ReaderSpecError, TopicTypeError, UnknownTypeError

LENGTHS = [6, 9, 7]
ARM_MSG = "my_robot_msgs/msg/ArmState.msg"


@pytest.fixture(autouse=True)
def _fresh_types() -> Iterator[None]:
    """Each read learns the lab's types as a new ``ompn_train`` process would (from the .msg files)."""
    tc.forget_lab_types()
    yield
    tc.forget_lab_types()


@pytest.fixture(scope="module")
def store() -> Any:
    return tc.lab_typestore()


def _bag_without_definitions(tmp_path: Path, store: Any) -> tuple[Path, tc.Demo]:
    demo = tc.demos(store, tc.COMMANDS["forward_command"], LENGTHS, seed=11)
    bag = tc.write_rosbags(tmp_path / "bag", store, demo, storage="sqlite3")
    edit_metadata(bag, lambda info: old_metadata(info, 5))
    old_sqlite_schema(storage_file(bag), 3)  # no message_definitions table: the types come from `types:`
    return bag, demo


def _spec(source: str) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "observation": {"topic": tc.STATE, "type": tc.ARM_STATE, "field": "positions"},
        "action": {"topic": tc.CMD, "type": "std_msgs/msg/Float64MultiArray", "field": "data"},
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5,
        "types": [source],
    })


def _read(bag: Path, source: str, cache: Path, workers: int) -> Any:
    tc.forget_lab_types()  # a new process: its typestore knows only what this read registers
    return load_arrays(bag, spec=_spec(source), cache_dir=cache, workers=workers)


def _edit(folder: Path, old: str, new: str) -> None:
    msg = folder / ARM_MSG
    text = msg.read_text(encoding="utf-8")
    assert old in text
    msg.write_text(text.replace(old, new), encoding="utf-8")


@pytest.mark.parametrize("workers", [0, 1])  # one entry for all the bags; per-bag entries
def test_a_renamed_field_is_not_served_from_the_stale_entry(tmp_path: Path, store: Any, workers: int) -> None:
    bag, demo = _bag_without_definitions(tmp_path, store)
    folder = tc.write_msg_folder(tmp_path / "src")
    first = _read(bag, str(folder), tmp_path / "cache", workers)
    assert not first.cache_hit
    np.testing.assert_allclose(first.observations, np.concatenate(demo.positions).astype(np.float32))
    assert _read(bag, str(folder), tmp_path / "cache", workers).cache_hit  # the same files: a hit
    _edit(folder, "float64[] positions", "float64[] joint_positions")
    with pytest.raises((ReaderSpecError, TopicTypeError, UnknownTypeError)) as err:
        _read(bag, str(folder), tmp_path / "cache", workers)
    assert "positions" in str(err.value) and "joint_positions" in str(err.value)


def test_a_retyped_field_is_read_along_the_new_definition(tmp_path: Path, store: Any) -> None:
    """float64 -> float32: the recorded bytes no longer fit the definition, so the read stops in one
    line naming the field, instead of handing out the entry built with the old definition."""
    bag, _ = _bag_without_definitions(tmp_path, store)
    folder = tc.write_msg_folder(tmp_path / "src")
    assert not _read(bag, str(folder), tmp_path / "cache", 0).cache_hit
    _edit(folder, "float64[] positions\nfloat64[] velocities", "float32[] positions\nfloat32[] velocities")
    with pytest.raises(CorruptBagError) as err:
        _read(bag, str(folder), tmp_path / "cache", 0)
    assert "'positions' of my_robot_msgs/msg/ArmState" in str(err.value) and "\n" not in str(err.value)


def test_an_installed_packages_msg_files_are_in_the_key(tmp_path: Path, store: Any,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    bag, demo = _bag_without_definitions(tmp_path, store)
    prefix = tmp_path / "install"
    tc.write_msg_folder(prefix / "share")  # share/my_robot_msgs/msg/*.msg, as colcon installs it
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    first = _read(bag, "my_robot_msgs", tmp_path / "cache", 0)
    np.testing.assert_allclose(first.observations, np.concatenate(demo.positions).astype(np.float32))
    assert _read(bag, "my_robot_msgs", tmp_path / "cache", 0).cache_hit
    _edit(prefix / "share", "float64[] positions", "float64[] joint_positions")
    with pytest.raises((ReaderSpecError, TopicTypeError, UnknownTypeError)):
        _read(bag, "my_robot_msgs", tmp_path / "cache", 0)
