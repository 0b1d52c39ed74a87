"""Field paths read from raw CDR (ompn_ros.data.messages.fieldpath) equal what rosbags deserializes, for
every kind of field, one message at a time and in bulk over messages of changing layouts; and types
registered from an installed package's share folder."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import type_corpus as tc

from ompn_ros.data import messages as m
from ompn_ros.data.messages.cdr import CdrError
from ompn_ros.data.messages.fieldpath import FieldPathError, FieldReader, RowError, describe
from ompn_ros.data.messages.types import TypeDefinitionError, ensure, known, register_sources

POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRAJ = "trajectory_msgs/msg/JointTrajectory"


def _pose(store: Any, k: int, frame: str = "map") -> Any:
    t = store.types
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.0 * k, y=2.0, z=3.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    cov = np.arange(36, dtype=np.float64) + k
    return t[POSE](
        header=tc._header(store, 10**9 + k),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
    )


def _traj(store: Any, k: int, points: int, names: list[str]) -> Any:
    t = store.types
    pts = [
        t["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=np.arange(len(names), dtype=np.float64) + 10 * i + k,
            velocities=np.zeros(0),
            accelerations=np.zeros(0),
            effort=np.zeros(0),
            time_from_start=t["builtin_interfaces/msg/Duration"](sec=i, nanosec=5),
        )
        for i in range(points)
    ]
    return t[TRAJ](header=tc._header(store, k), joint_names=names, points=pts)


@pytest.mark.parametrize("little", [True, False])
def test_fixed_arrays_scalars_and_nested_messages_equal_rosbags(little: bool) -> None:
    store = m.typestore()
    msg = _pose(store, 3)
    raw = bytes(store.serialize_cdr(msg, POSE, little_endian=little))
    reader = FieldReader(
        POSE,
        [
            "pose.covariance",
            "pose.covariance[-1]",
            "pose.pose.position",
            "pose.pose.orientation.w",
            "header.stamp",
        ],
    )
    cov, last, position, w, stamp = reader.values(raw)
    np.testing.assert_array_equal(cov, msg.pose.covariance)
    assert last.tolist() == [msg.pose.covariance[-1]] and w.tolist() == [1.0]
    assert position.tolist() == [3.0, 2.0, 3.0] and stamp.tolist() == [1, 3]
    assert describe(POSE, "pose.pose.position").labels == ("x", "y", "z")
    assert describe(POSE, "pose.covariance").labels == tuple(str(i) for i in range(36))
    assert describe(TRAJ, "joint_names[0]").kind == "string"  # a label, never an observation


def test_bulk_reads_changing_layouts_row_by_row_as_one_at_a_time() -> None:
    """Joint names of other lengths, a frame id that changes, trajectories of 1 to 3 points: every row
    of the bulk read equals the message read alone."""
    store = m.typestore()
    rng = np.random.default_rng(0)
    raws = []
    for k in range(60):
        names = ["a", "bb", "ccc"] if k % 3 else ["shoulder", "elbow", "w"]
        msg = _traj(store, k, int(rng.integers(1, 4)), names)
        msg.header.frame_id = "base" if k % 5 else "base_link_long"
        raws.append(bytes(store.serialize_cdr(msg, TRAJ)))
    reader = FieldReader(TRAJ, ["points[-1].positions", "points[0].time_from_start"])
    bulk = reader.vectors(raws)
    for i, raw in enumerate(raws):
        one = reader.values(raw)
        np.testing.assert_array_equal(bulk[0][i], one[0])
        np.testing.assert_array_equal(bulk[1][i], one[1])
        msg = store.deserialize_cdr(raw, TRAJ)
        np.testing.assert_array_equal(one[0], msg.points[-1].positions)


def test_a_message_that_cannot_give_the_path_is_named() -> None:
    store = m.typestore()
    raws = [
        bytes(store.serialize_cdr(_traj(store, k, 2 if k != 4 else 0, ["a", "b"]), TRAJ)) for k in range(8)
    ]
    reader = FieldReader(TRAJ, ["points[-1].positions"])
    with pytest.raises(RowError) as err:
        reader.vectors(raws)
    assert err.value.row == 4 and "outside 'points' of 0 elements" in err.value.detail
    with pytest.raises(CdrError):
        reader.values(raws[0][:30])  # cut inside the first point


@pytest.mark.parametrize(
    "path,words",
    [
        ("points[-1].postions", ["JointTrajectoryPoint has no field 'postions'", "positions, velocities"]),
        ("joint_names", ["leads to string[]"]),
        ("header[0]", ["'header' is not an array"]),
        ("points.positions[", ["not 'name' or 'name[index]'"]),
    ],
)
def test_path_errors_name_type_path_and_fields(path: str, words: list[str]) -> None:
    with pytest.raises(FieldPathError) as err:
        FieldReader(TRAJ, [path])
    assert all(w in str(err.value) for w in words), str(err.value)


@pytest.fixture
def _no_lab_types() -> Iterator[None]:
    tc.forget_lab_types()
    yield
    tc.forget_lab_types()


@pytest.mark.usefixtures("_no_lab_types")
def test_an_installed_package_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``types: [my_robot_msgs]`` finds ``share/my_robot_msgs/msg`` in AMENT_PREFIX_PATH."""
    share = tmp_path / "prefix" / "share"
    tc.write_msg_folder(share)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    assert not known(tc.ARM_STATE)
    register_sources(["my_robot_msgs"])
    assert known(tc.ARM_STATE) and known(tc.GRIPPER_STATE)
    assert describe(tc.ARM_STATE, "gripper").labels == ("width", "force", "grasped")


@pytest.mark.usefixtures("_no_lab_types")
def test_a_type_no_source_defines_names_the_way_out(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    with pytest.raises(
        TypeDefinitionError,
        match=r"my_robot_msgs/msg/ArmState is not in the bag's "
        r"definitions nor the typestore: name its \.msg folder",
    ):
        ensure(tc.ARM_STATE)
    with pytest.raises(TypeDefinitionError, match="neither a folder nor an installed interface package"):
        register_sources(["acme_msgs"])
