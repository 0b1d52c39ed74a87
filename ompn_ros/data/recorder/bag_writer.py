"""Write Episodes to a rosbag2 (metadata v9, mcap or sqlite3) following the step contract.

This is the ``ompn_collect`` route (no DDS).  Per episode, with synthetic stamps from
``ompn_ros.layout`` (``t0`` = episode start)::

    t0                                 episode start marker (task, seed, sketch, episode index)
    t0 + TOPIC_OFFSET_NS               sketch (Int32MultiArray)
    t0 + (t+1)*STEP_NS + k*TOPIC_OFFSET_NS   k-th topic of domain.step_topics at step t < T
                                       (observation, [joint_states], subtask, action)
    t0 + (T+1)*STEP_NS                 observation_T (+ joint_states_T when extras has T+1 rows)
    t0 + (T+1)*STEP_NS + 10*TOPIC_OFFSET_NS   episode end marker (steps, success)

An episode whose ``extras['observation_copies']`` (:data:`~ompn_ros.data.episode.OBSERVATION_COPIES`,
the human-like demonstrator's dropped and duplicated messages) says 0 has no observation message
at that step, and one that says 2 has a second copy 1 ns after the first.

and the next episode starts ``EPISODE_GAP_NS`` after the end marker.  Topics are absolute names
under ``namespace`` (default ``/``).  Storage goes through
:class:`ompn_ros.data.recorder.storage.DurableWriter`
(CRC'd mcap chunks, a commit at least every second).  JointState (dial) comes from ``episode.extras``:
``joint_position`` ``[T+1 | T, J]`` (required to publish), optional ``joint_velocity``,
``joint_effort`` of the same shape, and ``joint_names`` (default ``joint_0..``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.episode import Episode, observation_copies
from ompn_ros.data.errors import BagError
from ompn_ros.data.recorder.storage import DurableWriter
from ompn_ros.layout import DomainLayout, resolve_topic

STORAGES = ("mcap", "sqlite3")
END_MARKER_OFFSET_NS = 10 * layout.TOPIC_OFFSET_NS


def storage_plugin(storage: str) -> Any:
    """``rosbags`` StoragePlugin for ``'mcap'`` or ``'sqlite3'``."""
    from rosbags.rosbag2 import StoragePlugin

    if storage not in STORAGES:
        raise ValueError(f"unknown storage '{storage}', expected one of {STORAGES}")
    return StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3


@dataclass
class WriteStats:
    """What a writer wrote."""

    episodes: int = 0
    steps: int = 0
    messages: dict[str, int] = field(default_factory=dict)
    end_ns: int = 0

    @property
    def total_messages(self) -> int:
        return sum(self.messages.values())


class EpisodeBagWriter:
    """Context manager writing Episodes one by one into a new bag directory.

    Example::

        with EpisodeBagWriter(out_dir, layout.CRAFT, storage="mcap") as w:
            for ep in episodes:
                w.write_episode(ep)
    """

    def __init__(
        self,
        path: str | Path,
        domain: DomainLayout,
        *,
        storage: str = "mcap",
        namespace: str = "/",
        start_ns: int = layout.EPISODE_GAP_NS,
        first_episode_index: int = 0,
    ) -> None:
        self.path = Path(path)
        self.domain = domain
        self.storage = storage
        self.namespace = namespace
        self._plugin = storage_plugin(storage)
        self._cursor = int(start_ns)
        self._next_index = int(first_episode_index)
        self._writer: Any = None
        self._conns: dict[str, Any] = {}
        self.stats = WriteStats()

    def open(self) -> EpisodeBagWriter:
        if self.path.exists():
            raise BagError("output exists; the writer never overwrites a bag", path=self.path)
        self._writer = DurableWriter(self.path, version=9, storage_plugin=self._plugin)
        self._writer.open()
        ts = m.register_interfaces()  # EpisodeMarker
        for name, typename in layout.topic_types(self.domain).items():
            if name in (layout.RENDER, layout.EPISODE):
                continue  # no renderer; the markers are typed (the sims also publish the deprecated form)
            topic = resolve_topic(name, self.namespace)
            self._conns[name] = self._writer.add_connection(topic, typename, typestore=ts)
            self.stats.messages[topic] = 0
        return self

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> EpisodeBagWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def _markers(self, kind: str, stamp: int, values: dict[str, object]) -> None:
        """An episode marker, typed (``EpisodeMarker`` on ``episode_marker``)."""
        self._write(layout.EPISODE_MARKER, stamp, m.encode_typed_marker(kind, stamp, values))

    def _write(self, name: str, stamp: int, raw: bytes) -> None:
        conn = self._conns[name]
        self._writer.write(conn, stamp, raw)
        self.stats.messages[conn.topic] += 1

    def write_episode(self, episode: Episode, episode_index: int | None = None) -> int:
        """Write one episode; returns the stamp (ns) of its end marker."""
        if self._writer is None:
            raise RuntimeError("EpisodeBagWriter is not open")
        dom = self.domain
        obs = np.asarray(episode.observations, dtype=np.float32)
        if obs.shape[1] != dom.obs_dim:
            raise ValueError(f"episode '{episode.task}' (seed {episode.seed}) has observation size "
                             f"{obs.shape[1]}, domain '{dom.name}' expects {dom.obs_dim}")
        index = self._next_index if episode_index is None else int(episode_index)
        self._next_index = index + 1
        T = episode.length
        t0 = self._cursor
        off = layout.TOPIC_OFFSET_NS
        sketch = None if episode.sketch is None else np.asarray(episode.sketch, dtype=np.int64)

        start = m.start_marker_values(index, episode.task, episode.seed, sketch)
        self._markers(layout.EPISODE_START, t0, start)
        if sketch is not None:
            self._write(layout.SKETCH, t0 + off, m.serialize(m.int32_array(sketch)))

        joints = _joint_arrays(episode, dom)
        obs_raw = [m.encode_float32_array(row, "obs") for row in obs]
        copies = observation_copies(episode)
        act_raw = _action_raws(episode, dom)
        sub = None if episode.subtask is None else np.asarray(episode.subtask, dtype=np.int64)
        slot = {name: k for k, name in enumerate(dom.step_topics)}
        for t in range(T + 1):
            base = t0 + (t + 1) * layout.STEP_NS
            for copy in range(int(copies[t])):
                self._write(layout.OBSERVATION, base + slot[layout.OBSERVATION] * off + copy, obs_raw[t])
            if joints is not None and t < len(joints[1]):
                stamp = base + slot[layout.JOINT_STATES] * off
                names, pos, vel, eff = joints
                self._write(layout.JOINT_STATES, stamp, m.serialize(m.joint_state(
                    stamp, names, pos[t], () if vel is None else vel[t], () if eff is None else eff[t])))
            if t == T:
                break
            if sub is not None:
                self._write(layout.SUBTASK, base + slot[layout.SUBTASK] * off, m.encode_int32(sub[t]))
            self._write(layout.ACTION, base + slot[layout.ACTION] * off, act_raw[t])
        end = t0 + (T + 1) * layout.STEP_NS + END_MARKER_OFFSET_NS
        self._markers(layout.EPISODE_END, end, m.end_marker_values(index, episode.task, episode.seed, T,
                                                                   episode.success))
        self._cursor = end + layout.EPISODE_GAP_NS
        self.stats.episodes += 1
        self.stats.steps += T
        self.stats.end_ns = end
        return end


def _action_raws(episode: Episode, dom: DomainLayout) -> list[bytes]:
    actions = np.asarray(episode.actions)
    if dom.action_type == "discrete":
        if actions.ndim != 1:
            raise ValueError(f"domain '{dom.name}' has discrete actions; got shape {actions.shape}")
        return [m.encode_int32(a) for a in actions]
    if actions.ndim != 2 or actions.shape[1] != dom.action_dim:
        raise ValueError(f"domain '{dom.name}' expects actions [T, {dom.action_dim}], got {actions.shape}")
    return [m.encode_float32_array(a, "action") for a in actions]


def _joint_arrays(
    episode: Episode, dom: DomainLayout
) -> tuple[list[str], np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    if not dom.has_joint_states or "joint_position" not in episode.extras:
        return None
    pos = np.asarray(episode.extras["joint_position"], dtype=np.float64)
    if pos.ndim != 2 or len(pos) not in (episode.length, episode.length + 1):
        raise ValueError(f"extras['joint_position'] must be [T+1 or T, J], got {pos.shape}")
    vel = episode.extras.get("joint_velocity")
    eff = episode.extras.get("joint_effort")
    names = list(episode.extras.get("joint_names") or [f"joint_{i}" for i in range(pos.shape[1])])
    return (names, pos, None if vel is None else np.asarray(vel, np.float64),
            None if eff is None else np.asarray(eff, np.float64))


def write_episodes(
    path: str | Path,
    episodes: Iterable[Episode],
    domain: DomainLayout | str,
    *,
    storage: str = "mcap",
    namespace: str = "/",
    first_episode_index: int = 0,
) -> WriteStats:
    """Write ``episodes`` into a new bag directory ``path``; returns the write statistics."""
    dom = layout.DOMAINS[domain] if isinstance(domain, str) else domain
    with EpisodeBagWriter(path, dom, storage=storage, namespace=namespace,
                          first_episode_index=first_episode_index) as writer:
        for episode in episodes:
            writer.write_episode(episode)
    return writer.stats
