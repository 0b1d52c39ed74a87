"""A consumer of ``ompn_node``'s boundaries: one progress line per finished subtask.

The pattern to copy for your own node: subscribe to ``<node>/boundary``
(``ompn_interfaces/msg/SubtaskBoundary``) with the node's QoS (RELIABLE, TRANSIENT_LOCAL) and read
named fields.  The same messages are in bags annotated by ``ompn_segment --annotate``.

    python examples/subtask_progress.py --ros-args -p boundary_topic:=/ompn_node/boundary

prints, per boundary, e.g.::

    [/ompn_node] episode 3: subtask 2 (id 7) done at step 41, score 0.83, decided 1 step later
    [/ompn_node] episode 3 finished: 4 subtasks, last step 57

One message per finished subtask (``kind`` ``SUBTASK_END``), never repeated; every episode ends with
exactly one ``final`` message: its last subtask's end, or an ``EPISODE_END`` that reports no subtask
(the end of the last subtask came before).  No deduplication is needed.  Only rclpy and
``ompn_interfaces`` are needed.
"""

from __future__ import annotations

from typing import Any

EPISODE_END = 1  # SubtaskBoundary.EPISODE_END (the constant of the message, kept ROS-free here)


class Progress:
    """Turns boundaries into progress lines (ROS-free: the node below feeds it messages)."""

    def lines(self, msg: Any) -> list[str]:
        """The lines for one ``SubtaskBoundary`` (``msg`` has its fields as attributes)."""
        out = []
        ended_subtask = msg.kind != EPISODE_END
        if ended_subtask:
            known = f" (id {msg.subtask_id})" if msg.subtask_id >= 0 else ""
            lag = msg.decided_step - msg.step
            out.append(f"[{msg.node}] episode {msg.episode}: subtask {msg.subtask}{known} done at step "
                       f"{msg.step}, score {msg.score:.2f}, decided {lag} step{'s' * (lag != 1)} later")
        if msg.final:  # the episode's subtasks: ordinals 0 .. subtask (an episode end carries the count)
            subtasks = msg.subtask + 1 if ended_subtask else msg.subtask
            out.append(f"[{msg.node}] episode {msg.episode} finished: {subtasks} subtasks, "
                       f"last step {msg.step}")
        return out


def main() -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from ompn_interfaces.msg import SubtaskBoundary

    rclpy.init()
    node = rclpy.create_node("subtask_progress")
    topic = node.declare_parameter("boundary_topic", "/ompn_node/boundary").value
    progress = Progress()

    def on_boundary(msg: SubtaskBoundary) -> None:
        for line in progress.lines(msg):
            print(line, flush=True)

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(SubtaskBoundary, topic, on_boundary, qos)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
