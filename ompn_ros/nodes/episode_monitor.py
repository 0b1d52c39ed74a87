"""episode_monitor: print one JSON line per finished sim episode (closed-loop evaluation over ROS).

Subscribes (names from :mod:`ompn_ros.layout`, relative to the namespace) ``episode`` (start/end
markers), ``subtask`` (ground-truth ordinal per step) and ``observation`` (only so that a sim waiting
for two ``observation`` subscribers also waits for this monitor).  On every end marker it prints::

    {"event": "end", "episode": i, "task": ..., "seed": s, "steps": T, "success": bool,
     "max_subtask": k, "n_subtasks": K}

``max_subtask`` is the highest ordinal published in the episode (= subtasks completed before the
last step); ``actions`` = the executed discrete actions on ``action`` if ``record_actions`` (Craft),
else [].  Parameters: ``episodes`` (exit after this many end markers, 0 = never), ``timeout``
(seconds, exit code 3 when reached); an invalid parameter exits 2 with one line naming it.
First line printed once subscriptions exist: ``{"event": "ready"}``.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray, Int32

from ompn_ros import layout
from ompn_ros.ros.params import ParamSpec, ParamTable
from ompn_ros.ros.run import run_node

NODE_NAME = "episode_monitor"
GRACE_S = 0.5  # wait this long after an end marker for the episode's last per-step messages

QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


PARAMS = ParamTable((
    ParamSpec("episodes", 0, "exit after this many end markers (0 = never)", int_range=(0, 10_000_000)),
    ParamSpec("timeout", 600.0, "seconds before giving up (exit code 3)", float_range=(0.001, 1e9)),
    ParamSpec("record_actions", False, "collect the discrete actions of each episode (Craft)"),
))  # fmt: skip


class EpisodeMonitor(Node):
    """Collects per-episode outcomes from a sim's markers and subtask topic."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = PARAMS.declare(self)  # ParameterError on an invalid value
        self.episodes = int(values["episodes"])
        self.timeout = float(values["timeout"])
        self.finished_count = 0
        self.max_subtask = -1
        self.n_subtasks = 0
        self.deadline = time.monotonic() + self.timeout
        self.create_subscription(DiagnosticArray, layout.EPISODE, self._on_episode, QOS)
        self.create_subscription(Int32, layout.SUBTASK, self._on_subtask, QOS)
        self.create_subscription(Float32MultiArray, layout.OBSERVATION, lambda _msg: None, QOS)
        self.actions: list[int] = []
        self._pending: tuple[dict[str, Any], float] | None = None
        self.record_actions = bool(values["record_actions"])
        if self.record_actions:  # discrete (Craft) action labels
            self.create_subscription(Int32, layout.ACTION, self._on_action, QOS)
        print(json.dumps({"event": "ready"}), flush=True)

    def _on_subtask(self, msg: Int32) -> None:
        self.max_subtask = max(self.max_subtask, int(msg.data))

    def _on_action(self, msg: Int32) -> None:
        self.actions.append(int(msg.data))
        self.flush()

    def _on_episode(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != layout.EPISODE_STATUS_NAME:
                continue
            values: dict[str, Any] = {kv.key: kv.value for kv in status.values}
            if status.message == layout.EPISODE_START:
                self.flush(force=True)
                self.max_subtask = -1
                self.actions = []
                sketch = values.get(layout.KEY_SKETCH, "")
                self.n_subtasks = len([s for s in sketch.split(",") if s.strip()])
            elif status.message == layout.EPISODE_END:
                # Messages on other topics may still be in flight: finish once all `steps` actions
                # arrived (or after a grace period), see flush().
                self._pending = (values, time.monotonic() + GRACE_S)
        self.flush()

    def flush(self, force: bool = False) -> None:
        """Print the pending end record once complete, its grace period is over, or ``force``."""
        if self._pending is None:
            return
        values, until = self._pending
        steps = int(values.get(layout.KEY_STEPS, 0))
        complete = self.record_actions and len(self.actions) >= steps
        if not (complete or force or time.monotonic() >= until):
            return
        record = {
            "event": "end",
            "episode": int(values.get(layout.KEY_EPISODE, -1)),
            "task": values.get(layout.KEY_TASK, ""),
            "seed": int(values.get(layout.KEY_SEED, -1)),
            "steps": steps,
            "success": values.get(layout.KEY_SUCCESS, "false") == "true",
            "max_subtask": self.max_subtask,
            "n_subtasks": self.n_subtasks,
            "actions": list(self.actions),
        }
        print(json.dumps(record), flush=True)
        self._pending = None
        self.finished_count += 1

    @property
    def done(self) -> bool:
        return bool(self.episodes) and self.finished_count >= self.episodes

    def poll(self) -> int | None:
        """After every wait: print the pending record when due; exit code 0 after ``episodes`` records,
        3 (with a timeout line) once ``timeout`` has passed, else ``None``."""
        self.flush()
        if time.monotonic() > self.deadline:
            print(json.dumps({"event": "timeout", "finished": self.finished_count}), flush=True)
            return 3
        return 0 if self.done else None


def main(args: list[str] | None = None) -> int:
    """Exit codes: 0 done or interrupted, 2 invalid parameter (one line), 3 timeout."""
    return run_node(NODE_NAME, EpisodeMonitor, args, about="Prints one JSON line per finished sim episode.",
                    params=PARAMS.specs.values(), serve=lambda node, process: process.serve(node.poll))


if __name__ == "__main__":
    sys.exit(main())
