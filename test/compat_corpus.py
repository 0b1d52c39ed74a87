"""Bags of another lab for the compatibility tests: written with ``rosbags`` (or the ``mcap`` package),
never with this package's writer.

The robot publishes a ``Float32MultiArray`` state on ``/lab/state`` at 25 Hz and a
``Float32MultiArray`` command on ``/lab/cmd`` 2 ms after each state except the last of a
demonstration (so the last state is the final observation); demonstrations are 2 s apart.
:data:`SPEC` reads them; :func:`check_episodes` compares what was read with what was written.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.episode import Episode

STATE, CMD = "/lab/state", "/lab/cmd"
OBS_DIM, ACT_DIM = 4, 2
STEP_NS, GAP_NS = 40_000_000, 2_000_000_000
SPEC = ReaderSpec.from_dict({
    "observation": {"topic": STATE, "type": layout.FLOAT32_ARRAY, "dim": OBS_DIM},
    "action": {"topic": CMD, "type": layout.FLOAT32_ARRAY, "dim": ACT_DIM},
    "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5,
})


@dataclass
class Demo:
    """What was written: per demonstration, the states ``[T + 1, D]`` and commands ``[T, A]``."""

    observations: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    messages: list[tuple[int, str, bytes]] = field(default_factory=list)  # (log stamp, topic, CDR)
    labels: list[np.ndarray] = field(default_factory=list)  # per step, where written


def demos(lengths: list[int], seed: int = 0, t0: int = 10**9) -> Demo:
    """Demonstrations of ``lengths`` steps, their messages in log-stamp order."""
    rng = np.random.default_rng(seed)
    out = Demo()
    t = t0
    for steps in lengths:
        obs = rng.standard_normal((steps + 1, OBS_DIM)).astype(np.float32)
        act = rng.standard_normal((steps, ACT_DIM)).astype(np.float32)
        for k in range(steps + 1):
            stamp = t + k * STEP_NS
            out.messages.append((stamp, STATE, m.serialize(m.float32_array(obs[k], "state"))))
            if k < steps:
                out.messages.append((stamp + 2_000_000, CMD, m.serialize(m.float32_array(act[k], "cmd"))))
        out.observations.append(obs)
        out.actions.append(act)
        t += steps * STEP_NS + GAP_NS
    return out


def write_rosbags(path: Path, demo: Demo, *, storage: str = "mcap", version: int = 9,
                  compression: str | None = None) -> Path:
    """A rosbag2 bag of ``demo`` written by ``rosbags`` (``compression``: 'file' or 'message', zstd)."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=version, storage_plugin=plugin)  # type: ignore[arg-type]
    if compression is not None:
        writer.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
    with writer:
        conns = {topic: writer.add_connection(topic, layout.FLOAT32_ARRAY, typestore=m.typestore())
                 for topic in (STATE, CMD)}
        for stamp, topic, raw in demo.messages:
            writer.write(conns[topic], stamp, raw)
    return path


def storage_file(bag: Path) -> Path:
    """The one storage file of ``bag``."""
    (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3") or ".mcap." in p.name
               or ".db3." in p.name]
    return file


def check_episodes(got: list[Episode], demo: Demo) -> None:
    """Every demonstration read back value for value."""
    assert len(got) == len(demo.observations), [e.length for e in got]
    for ep, obs, act in zip(got, demo.observations, demo.actions):
        np.testing.assert_array_equal(ep.observations, obs)
        np.testing.assert_array_equal(ep.actions, act)


def read_and_check(paths: object, demo: Demo, spec: ReaderSpec = SPEC, **kw: object) -> object:
    """``read_episodes`` then :func:`check_episodes`; returns the read report."""
    result = read_episodes(paths, spec=spec, **kw)  # type: ignore[arg-type]
    check_episodes(result.episodes, demo)
    return result.report


JAZZY_RELIABLE_QOS = """- history: keep_last
  depth: 10
  reliability: reliable
  durability: volatile
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: automatic
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false
"""
"""An ``offered_qos_profiles`` string as ``ros2 bag record`` (Jazzy, metadata version 9) writes it."""


def edit_metadata(bag: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    """Apply ``edit`` to ``rosbag2_bagfile_information`` of ``bag``'s metadata.yaml."""
    meta = bag / "metadata.yaml"
    data = yaml.safe_load(meta.read_text(encoding="utf-8"))
    edit(data["rosbag2_bagfile_information"])
    meta.write_text(yaml.safe_dump(data), encoding="utf-8")


def set_qos(info: dict[str, Any], topics: tuple[str, ...], qos: str = JAZZY_RELIABLE_QOS) -> None:
    """metadata.yaml's QoS string of ``topics`` (the storage file keeps its own)."""
    for entry in info["topics_with_message_count"]:
        if entry["topic_metadata"]["name"] in topics:
            entry["topic_metadata"]["offered_qos_profiles"] = qos


def write_split(path: Path, demo: Demo, cuts: list[int], *, storage: str = "mcap",
                compression: str | None = None, metadata: bool = True) -> list[Path]:
    """``demo`` as a split bag: rosbag2's ``<dir>_<n>.<ext>`` files, a new file at each stamp of ``cuts``;
    with ``metadata``, the metadata.yaml rosbag2 writes when the recording ends (otherwise none, as a
    recorder that crashed leaves it).  Returns the storage files in split order."""
    path.mkdir()
    bounds = [-1, *cuts, 2**62]
    files, infos = [], []
    for k in range(len(bounds) - 1):
        part = Demo(messages=[x for x in demo.messages if bounds[k] <= x[0] < bounds[k + 1]])
        bag = write_rosbags(path.parent / f".part{k}", part, storage=storage, compression=compression)
        file = storage_file(bag)
        files.append(file.rename(path / f"{path.name}_{k}{file.name[len(bag.name):]}"))
        infos.append(yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"])
    if metadata:
        info = infos[0]
        info["relative_file_paths"] = [f.name for f in files]
        info["files"] = [dict(i["files"][0], path=f.name) for i, f in zip(infos, files)]
        info["message_count"] = sum(i["message_count"] for i in infos)
        end = max(i["starting_time"]["nanoseconds_since_epoch"] + i["duration"]["nanoseconds"] for i in infos)
        info["duration"]["nanoseconds"] = end - info["starting_time"]["nanoseconds_since_epoch"]
        for k, entry in enumerate(info["topics_with_message_count"]):
            entry["message_count"] = sum(i["topics_with_message_count"][k]["message_count"] for i in infos)
        (path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return files


V8_QOS = ("- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 2147483647\n"
          "    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n"
          "  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
          "  avoid_ros_namespace_conventions: false")
"""``offered_qos_profiles`` as rosbag2 wrote it up to metadata version 8 (a YAML string, numeric enums)."""
KEYS_SINCE = {"files": 5, "custom_data": 6, "ros_distro": 8}
"""metadata.yaml keys and the version that added them (rosbag2's metadata version history)."""


def old_metadata(info: dict[str, Any], version: int) -> None:
    """metadata.yaml as rosbag2 wrote it at ``version`` (4 to 9): keys added later removed."""
    info["version"] = version
    for key, since in KEYS_SINCE.items():
        if version < since:
            info.pop(key, None)
    for entry in info["topics_with_message_count"]:
        if version < 7:
            entry["topic_metadata"].pop("type_description_hash", None)
        if version < 9:
            entry["topic_metadata"]["offered_qos_profiles"] = V8_QOS


def old_sqlite_schema(file: Path, schema: int) -> None:
    """Rewrite a ``.db3`` in an older rosbag2 schema: 1 (topics without QoS), 2 (QoS column) or 3
    (a ``schema`` table; no message definitions nor type hashes)."""
    old = file.with_suffix(".new")
    src = sqlite3.connect(file)
    dst = sqlite3.connect(old)
    qos = ", offered_qos_profiles TEXT NOT NULL" if schema >= 2 else ""
    dst.execute(f"CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
                f"serialization_format TEXT NOT NULL{qos})")
    dst.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, "
                "timestamp INTEGER NOT NULL, data BLOB NOT NULL)")
    if schema >= 3:
        dst.execute("CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL)")
        dst.execute("INSERT INTO schema VALUES (3, 'humble')")
    for row in src.execute("SELECT id, name, type, serialization_format FROM topics"):
        dst.execute(f"INSERT INTO topics VALUES (?, ?, ?, ?{', ?' if schema >= 2 else ''})",
                    (*row, V8_QOS) if schema >= 2 else row)
    dst.executemany("INSERT INTO messages VALUES (?, ?, ?, ?)",
                    src.execute("SELECT id, topic_id, timestamp, data FROM messages"))
    dst.commit()
    src.close()
    dst.close()
    old.replace(file)


ARM, ARM_CMD, SKILL = "/arm/joint_states", "/arm/command", "/arm/skill"
ARM_JOINTS = ("shoulder", "elbow", "wrist")
ROBOT_LATENCY_NS = 3_000_000
"""The robot's header stamps lead the recording PC's receive time by this much (a steady clock pair)."""


@dataclass
class ClockStep:
    """A clock set back (``size_ns`` < 0) or forward by ``size_ns`` just before observation
    ``at`` (counted over the whole bag) and every message after it."""

    at: int
    size_ns: int


def arm_demos(lengths: list[int], *, robot: ClockStep | None = None, pc: ClockStep | None = None,
              names: Callable[[int], tuple[str, ...]] | None = None, seed: int = 0) -> Demo:
    """A driver's arm: JointState states on :data:`ARM` (``header.stamp`` on the robot's clock), a
    ``Float32MultiArray`` command on :data:`ARM_CMD` 2 ms after each state but the last of a
    demonstration, an ``Int32`` skill id on :data:`SKILL` 1 ms after each state; 25 Hz, 2 s pauses.
    ``robot`` / ``pc``: the robot's (header) or the recording PC's (log) clock steps; ``names``: the
    joint names of observation ``k`` (the values follow the names: joint ``j`` holds
    ``positions[k, ARM_JOINTS.index(j)]``, a joint not in :data:`ARM_JOINTS` 0.5).  ``Demo.labels``
    holds the skill ids per step."""
    rng = np.random.default_rng(seed)
    out = Demo()
    t, k = 10**9, 0
    for steps in lengths:
        obs = rng.standard_normal((steps + 1, len(ARM_JOINTS)))
        act = rng.standard_normal((steps, ACT_DIM)).astype(np.float32)
        skills = np.repeat([7, 3, 9], steps // 3 + 1)[: steps + 1].astype(np.int64)
        for i in range(steps + 1):
            true = t + i * STEP_NS
            log = true + (pc.size_ns if pc is not None and k >= pc.at else 0)
            head = true - ROBOT_LATENCY_NS + (robot.size_ns if robot is not None and k >= robot.at else 0)
            order = names(k) if names is not None else ARM_JOINTS
            values = [obs[i, ARM_JOINTS.index(j)] if j in ARM_JOINTS else 0.5 for j in order]
            out.messages.append((log, ARM, m.serialize(m.joint_state(head, list(order), values, ()))))
            out.messages.append((log + 1_000_000, SKILL, m.serialize(m.int32(int(skills[i])))))
            if i < steps:
                out.messages.append((log + 2_000_000, ARM_CMD, m.serialize(m.float32_array(act[i], "cmd"))))
            k += 1
        out.observations.append(obs.astype(np.float32))
        out.actions.append(act)
        out.labels.append(skills[:steps])
        t += steps * STEP_NS + GAP_NS
    return out


ARM_SPEC = ReaderSpec.from_dict({
    "observation": {"topic": ARM, "type": layout.JOINT_STATE, "fields": ["position"]},
    "action": {"topic": ARM_CMD, "type": layout.FLOAT32_ARRAY, "dim": ACT_DIM},
    "subtask": SKILL, "labels": "id", "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5,
    "tolerance": 0.03, "strict": False, "final_observation": "require",
})
"""Reads :func:`arm_demos` on the recording PC's clock (``stamp: log``)."""


def write_arm(path: Path, demo: Demo, *, storage: str = "mcap") -> Path:
    """``demo`` of :func:`arm_demos` as a rosbag2 bag written by ``rosbags``, in the order recorded."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    types = {ARM: layout.JOINT_STATE, ARM_CMD: layout.FLOAT32_ARRAY, SKILL: layout.INT32}
    with Writer(path, version=9, storage_plugin=plugin) as writer:  # type: ignore[arg-type]
        conns = {topic: writer.add_connection(topic, kind, typestore=m.typestore())
                 for topic, kind in types.items()}
        for stamp, topic, raw in demo.messages:
            writer.write(conns[topic], stamp, raw)
    return path


def check_arm(got: list[Episode], demo: Demo) -> None:
    """Every demonstration of :func:`arm_demos` read back value for value, labels included."""
    check_episodes(got, demo)
    for ep, ids in zip(got, demo.labels):
        np.testing.assert_array_equal(ep.extras["subtask_id"], ids)


FLOAT32_ARRAY_MSGDEF = "std_msgs/MultiArrayLayout layout\nfloat32[] data\n" + "=" * 80 + (
    "\nMSG: std_msgs/MultiArrayLayout\nMultiArrayDimension[] dim\nuint32 data_offset\n" + "=" * 80
    + "\nMSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n")
"""``std_msgs/msg/Float32MultiArray`` as a ``ros2msg`` schema (what rosbag2 and Foxglove store)."""


def write_mcap(path: Path, messages: list[tuple[int, str, bytes]], *, profile: str = "ros2",
               indexed: bool = True) -> Path:
    """A bare ``.mcap`` of :data:`STATE` / :data:`CMD` written with the ``mcap`` package's writer, the
    messages in the order given (``profile``: the header's; ``indexed``: chunk and message indexes and a
    summary, else none, as a streaming writer leaves them)."""
    from mcap.writer import CompressionType, IndexType, Writer

    with open(path, "wb") as fh:
        writer = Writer(fh, index_types=IndexType.ALL if indexed else IndexType.NONE,
                        use_summary_offsets=indexed, use_statistics=indexed,
                        compression=CompressionType.NONE)
        writer.start(profile=profile, library="another lab's logger")
        schema = writer.register_schema(layout.FLOAT32_ARRAY, "ros2msg", FLOAT32_ARRAY_MSGDEF.encode())
        channels = {topic: writer.register_channel(topic, "cdr", schema) for topic in (STATE, CMD)}
        for k, (stamp, topic, raw) in enumerate(messages):
            writer.add_message(channels[topic], log_time=stamp, data=raw, publish_time=stamp, sequence=k)
        writer.finish()
    return path
