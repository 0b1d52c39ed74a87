"""Bags shaped like a real robot's, written with ``rosbags`` alone (its own Jazzy typestore, not this
package's codec): joint states published continuously, also while the robot idles, BEST_EFFORT, header
stamps on the robot's clock, commands only while a demonstration runs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
JOINT_STATE = "sensor_msgs/msg/JointState"
MS = 1_000_000
S = 1_000_000_000


def qos(reliability: QosReliability) -> Qos:
    zero = QosTime(0, 0)
    return Qos(QosHistory.KEEP_LAST, 10, reliability, QosDurability.VOLATILE, zero, zero,
               QosLiveliness.AUTOMATIC, zero, False)


BEST_EFFORT = [qos(QosReliability.BEST_EFFORT)]
RELIABLE = [qos(QosReliability.RELIABLE)]


def stamp(ns: int) -> Any:
    return TS.types["builtin_interfaces/msg/Time"](sec=ns // S, nanosec=ns % S)


def joint_state(ns: int, names: Sequence[str], position: Sequence[float] = (),
                velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> bytes:
    header = TS.types["std_msgs/msg/Header"](stamp=stamp(ns), frame_id="")
    msg = TS.types[JOINT_STATE](header=header, name=list(names),
                                position=np.asarray(position, np.float64),
                                velocity=np.asarray(velocity, np.float64),
                                effort=np.asarray(effort, np.float64))
    return bytes(TS.serialize_cdr(msg, JOINT_STATE))


def scalar(msgtype: str, value: Any) -> bytes:
    return bytes(TS.serialize_cdr(TS.types[msgtype](data=value), msgtype))


@dataclass
class BagWriter:
    """Messages collected per connection, written sorted by receive stamp on :meth:`write`."""

    path: Path
    storage: str = "mcap"
    topics: dict[str, tuple[str, list[Qos]]] = field(default_factory=dict)
    messages: list[tuple[int, str, bytes]] = field(default_factory=list)

    def add(self, topic: str, msgtype: str, receive_ns: int, raw: bytes,
            offered: list[Qos] | None = None) -> None:
        self.topics.setdefault(topic, (msgtype, offered if offered is not None else RELIABLE))
        self.messages.append((receive_ns, topic, raw))

    def write(self) -> Path:
        plugin = StoragePlugin.MCAP if self.storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(self.path, version=9, storage_plugin=plugin) as w:
            conns = {t: w.add_connection(t, kind, typestore=TS, offered_qos_profiles=offered)
                     for t, (kind, offered) in self.topics.items()}
            for receive, topic, raw in sorted(self.messages, key=lambda x: x[0]):
                w.write(conns[topic], receive, raw)
        return self.path
