"""Bags of labs whose robots publish their own and the standard command types, written with their tools
(``rosbags``' writer into sqlite3 or mcap, the ``mcap``/``mcap-ros2-support`` writer Foxglove uses),
each carrying the definition of its types as rosbag2 and Foxglove store it.

The robot publishes ``my_robot_msgs/msg/ArmState`` (header, ``string[] joint_names``,
``float64[] positions``, ``float64[] velocities``, a nested ``GripperState``) on ``/arm/state`` at
25 Hz and a command of one of :data:`COMMANDS` on ``/arm/cmd`` 2 ms after each state but the last of a
demonstration; demonstrations are 2 s apart.  The writer's typestore is its own: the reader learns the
custom types from the bag (or a ``.msg`` folder), never from the test.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

STATE, CMD = "/arm/state", "/arm/cmd"
JOINTS = ("shoulder", "elbow", "wrist")
STEP_NS, GAP_NS = 40_000_000, 2_000_000_000
ARM_STATE, GRIPPER_STATE = "my_robot_msgs/msg/ArmState", "my_robot_msgs/msg/GripperState"
JOINT_JOG = "control_msgs/msg/JointJog"
MSG_FILES = {
    ARM_STATE: "std_msgs/Header header\nstring[] joint_names\nfloat64[] positions\nfloat64[] velocities\n"
    "GripperState gripper\n",
    GRIPPER_STATE: "float64 width\nfloat32 force\nbool grasped\n",
}
"""The lab's interface package ``my_robot_msgs`` (what its ``msg/`` folder holds)."""
JOINT_JOG_MSG = (
    "std_msgs/Header header\nstring[] joint_names\nfloat64[] displacements\n"
    "float64[] velocities\nfloat64 duration\n"
)
"""``control_msgs/msg/JointJog`` (MoveIt Servo's joint command; not in the Jazzy typestore)."""
SEPARATOR = "=" * 80 + "\n"


def lab_typestore(gripper: str | None = None) -> Any:
    """The writing lab's typestore: Jazzy's plus its own and control_msgs' types (not the reader's);
    ``gripper``: another lab's definition of ``GripperState``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    files = {**MSG_FILES, **({GRIPPER_STATE: gripper} if gripper else {})}
    for name, text in (*files.items(), (JOINT_JOG, JOINT_JOG_MSG)):
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def write_msg_folder(root: Path) -> Path:
    """``root/my_robot_msgs/msg/*.msg``: the lab's package sources; returns ``root``."""
    folder = root / "my_robot_msgs" / "msg"
    folder.mkdir(parents=True)
    for name, text in MSG_FILES.items():
        (folder / f"{name.rsplit('/', 1)[1]}.msg").write_text(text, encoding="utf-8")
    return root


def forget_lab_types() -> None:
    """Drop the lab's types from the reader's typestore (each test learns them again)."""
    from ompn_ros.data.messages.types import forget

    forget([ARM_STATE, GRIPPER_STATE, JOINT_JOG])


@dataclass(frozen=True)
class Command:
    """A command type: its name, the reader's field path, the action width, a message builder
    (store, header stamp, action) -> message object, and its concatenated ``ros2msg`` definition."""

    msgtype: str
    path: str
    width: int
    build: Callable[[Any, int, np.ndarray], Any]


def _header(store: Any, stamp: int) -> Any:
    t = store.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    return store.types["std_msgs/msg/Header"](stamp=t, frame_id="base_link")


def _trajectory(store: Any, stamp: int, act: np.ndarray) -> Any:
    point, duration = (
        store.types["trajectory_msgs/msg/JointTrajectoryPoint"],
        store.types["builtin_interfaces/msg/Duration"],
    )
    empty = np.zeros(0)
    points = [
        point(
            positions=act * 0.5,
            velocities=empty,
            accelerations=empty,
            effort=empty,
            time_from_start=duration(sec=0, nanosec=20_000_000),
        ),
        point(
            positions=act.copy(),
            velocities=np.zeros(3),
            accelerations=empty,
            effort=empty,
            time_from_start=duration(sec=0, nanosec=40_000_000),
        ),
    ]
    return store.types["trajectory_msgs/msg/JointTrajectory"](
        header=_header(store, stamp), joint_names=list(JOINTS), points=points
    )


def _twist(store: Any, stamp: int, act: np.ndarray) -> Any:
    vec, twist = store.types["geometry_msgs/msg/Vector3"], store.types["geometry_msgs/msg/Twist"]
    return store.types["geometry_msgs/msg/TwistStamped"](
        header=_header(store, stamp),
        twist=twist(linear=vec(x=act[0], y=act[1], z=act[2]), angular=vec(x=0.0, y=0.0, z=0.0)),
    )


def _jog(store: Any, stamp: int, act: np.ndarray) -> Any:
    return store.types[JOINT_JOG](
        header=_header(store, stamp),
        joint_names=list(JOINTS),
        displacements=np.zeros(0),
        velocities=act.copy(),
        duration=0.1,
    )


def _forward(store: Any, stamp: int, act: np.ndarray) -> Any:
    layout = store.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
    return store.types["std_msgs/msg/Float64MultiArray"](layout=layout, data=act.copy())


COMMANDS = {
    "joint_trajectory": Command(
        "trajectory_msgs/msg/JointTrajectory", "points[-1].positions", 3, _trajectory
    ),
    "servo_twist": Command("geometry_msgs/msg/TwistStamped", "twist.linear", 3, _twist),
    "servo_jog": Command(JOINT_JOG, "velocities", 3, _jog),
    "forward_command": Command("std_msgs/msg/Float64MultiArray", "data", 3, _forward),
}
"""ros2_control's joint trajectory and forward command controllers, MoveIt Servo's two commands."""


@dataclass
class Demo:
    """What was written: per demonstration, states ``[T + 1, J]``, grippers ``[T + 1]``, actions
    ``[T, A]``; and every message as ``(log stamp, topic, msgtype, message object)``."""

    positions: list[np.ndarray] = field(default_factory=list)
    grippers: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    messages: list[tuple[int, str, str, Any]] = field(default_factory=list)


def demos(store: Any, command: Command, lengths: list[int], seed: int = 0, t0: int = 10**9) -> Demo:
    """Demonstrations of ``lengths`` steps, messages in log-stamp order (header = log stamp - 1 ms)."""
    rng = np.random.default_rng(seed)
    arm, grip = store.types[ARM_STATE], store.types[GRIPPER_STATE]
    out, t = Demo(), t0
    for steps in lengths:
        pos = rng.standard_normal((steps + 1, len(JOINTS)))
        width = rng.uniform(0.0, 0.08, steps + 1)
        act = rng.standard_normal((steps, command.width))
        for k in range(steps + 1):
            stamp = t + k * STEP_NS
            state = arm(
                header=_header(store, stamp - 1_000_000),
                joint_names=list(JOINTS),
                positions=pos[k],
                velocities=np.zeros(len(JOINTS)),
                gripper=grip(width=width[k], force=2.5, grasped=k > 2),
            )
            out.messages.append((stamp, STATE, ARM_STATE, state))
            if k < steps:
                out.messages.append(
                    (stamp + 2_000_000, CMD, command.msgtype, command.build(store, stamp + 2_000_000, act[k]))
                )
        out.positions.append(pos)
        out.grippers.append(width)
        out.actions.append(act)
        t += steps * STEP_NS + GAP_NS
    return out


def write_rosbags(path: Path, store: Any, demo: Demo, *, storage: str = "mcap", version: int = 9) -> Path:
    """``demo`` as a rosbag2 bag written by ``rosbags`` (definitions stored as rosbag2 does)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=version, storage_plugin=plugin) as writer:  # type: ignore[arg-type]
        conns: dict[tuple[str, str], Any] = {}
        for stamp, topic, msgtype, msg in demo.messages:
            key = (topic, msgtype)
            if key not in conns:
                conns[key] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[key], stamp, bytes(store.serialize_cdr(msg, msgtype)))
    return path


def _dependencies(store: Any, msgtype: str) -> Iterator[str]:
    """The message types ``msgtype`` uses, depth first, each once."""
    seen: set[str] = set()

    def visit(name: str) -> Iterator[str]:
        for _, (kind, detail) in store.fielddefs[name][1]:
            sub = detail if kind == 2 else (detail[0][1] if kind in (3, 4) and detail[0][0] == 2 else None)
            if sub is not None and sub not in seen:
                seen.add(sub)
                yield sub
                yield from visit(sub)

    yield from visit(msgtype)


def ros2msg(store: Any, msgtype: str) -> str:
    """The concatenated ``ros2msg`` definition rosbag2 and Foxglove store (own fields, then each
    dependency after a ``=`` line and ``MSG: pkg/Type``)."""
    texts = {
        ARM_STATE: MSG_FILES[ARM_STATE],
        GRIPPER_STATE: MSG_FILES[GRIPPER_STATE],
        JOINT_JOG: JOINT_JOG_MSG,
    }

    def text(name: str) -> str:
        if name in texts:
            return texts[name]
        return store.generate_msgdef(name, ros_version=2)[0].split(SEPARATOR)[0]

    parts = [text(msgtype)]
    for dep in _dependencies(store, msgtype):
        pkg, _, name = dep.split("/")
        parts.append(f"{SEPARATOR}MSG: {pkg}/{name}\n{text(dep)}")
    return "".join(parts)


def to_dict(msg: Any) -> Any:
    """A ``rosbags`` message object as the plain dict ``mcap_ros2``'s writer serializes."""
    if hasattr(msg, "__dataclass_fields__"):
        return {k: to_dict(getattr(msg, k)) for k in msg.__dataclass_fields__ if k != "__msgtype__"}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [to_dict(x) for x in msg]
    return msg


def write_foxglove(path: Path, store: Any, demo: Demo) -> Path:
    """``demo`` as a bare ``.mcap`` written by ``mcap_ros2``'s writer (Foxglove's tools), the custom
    definitions embedded as its schemas."""
    from mcap_ros2.writer import Writer as McapWriter

    with open(path, "wb") as fh:
        writer = McapWriter(fh)
        schemas: dict[str, Any] = {}
        for stamp, topic, msgtype, msg in demo.messages:
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_msgdef(msgtype, ros2msg(store, msgtype))
            writer.write_message(topic, schemas[msgtype], to_dict(msg), log_time=stamp, publish_time=stamp)
        writer.finish()
    return path


def check(got: list[Any], demo: Demo, *, gripper: bool = False) -> None:
    """Every demonstration read back value for value (float32 of what was written)."""
    assert len(got) == len(demo.positions), [e.length for e in got]
    for ep, pos, width, act in zip(got, demo.positions, demo.grippers, demo.actions):
        want = np.hstack([pos, width[:, None]]) if gripper else pos
        np.testing.assert_array_equal(ep.observations, want.astype(np.float32))
        np.testing.assert_array_equal(ep.actions, act.astype(np.float32))


IDL = {
    ARM_STATE: """#include "my_robot_msgs/msg/GripperState.idl"
#include "std_msgs/msg/Header.idl"

module my_robot_msgs {
  module msg {
    struct ArmState {
      std_msgs::msg::Header header;
      sequence<string> joint_names;
      sequence<double> positions;
      sequence<double> velocities;
      my_robot_msgs::msg::GripperState gripper;
    };
  };
};
""",
    GRIPPER_STATE: """module my_robot_msgs {
  module msg {
    struct GripperState {
      double width;
      float force;
      boolean grasped;
    };
  };
};
""",
}
"""The lab's types as the ``.idl`` files rosidl generates from its ``.msg`` files."""


def write_idl_mcap(path: Path, store: Any, demo: Demo) -> Path:
    """``demo`` as a bare ``.mcap`` written with the ``mcap`` package whose ArmState schema is
    ``ros2idl`` (rosbag2's concatenation: ``IDL: pkg/msg/Type`` sections between ``=`` lines), the other
    types' schemas ``ros2msg``."""
    from mcap.writer import Writer as McapWriter

    with open(path, "wb") as fh:
        writer = McapWriter(fh)
        writer.start(profile="ros2", library="lab")
        channels: dict[str, int] = {}
        for stamp, topic, msgtype, msg in demo.messages:
            if topic not in channels:
                if msgtype == ARM_STATE:
                    text = "".join(f"{SEPARATOR}IDL: {name}\n{IDL[name]}" for name in IDL)
                    schema = writer.register_schema(msgtype, "ros2idl", text.encode())
                else:
                    schema = writer.register_schema(msgtype, "ros2msg", ros2msg(store, msgtype).encode())
                channels[topic] = writer.register_channel(topic, "cdr", schema)
            writer.add_message(channels[topic], log_time=stamp, data=bytes(store.serialize_cdr(msg, msgtype)),
                               publish_time=stamp)
        writer.finish()
    return path
