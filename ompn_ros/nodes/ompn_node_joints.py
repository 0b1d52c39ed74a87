"""``ompn_node``'s joint-state input (``obs_source: joint_state``), surviving any message.

:class:`JointStates` is the part of the node's inputs (:mod:`ompn_ros.nodes.ompn_node_inputs`) that turns
``sensor_msgs/JointState`` messages into observations stamped by their headers, by the reader's rules
(:class:`~ompn_ros.nodes.ompn_node_obs.JointInput`: ``joint_fields`` of the joints in ``joint_names``
order, several publishers merged with ``joint_merge``); a message sent twice is one step.  Topics,
stamps and QoS: the module docstring of :mod:`ompn_ros.nodes.ompn_node`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.lifecycle import LifecycleNode
from sensor_msgs.msg import JointState

from ompn_ros import layout
from ompn_ros.data.messages import StampRangeError, join_stamp
from ompn_ros.nodes.ompn_node_obs import JointInput
from ompn_ros.nodes.ompn_node_outputs import NodePublishers
from ompn_ros.stream.clock import classify_stamp
from ompn_ros.validate import BadStamp, FutureStamp, InvalidInput, MalformedMessage

__all__ = ["JointStates"]


class JointStates:
    """The callback of the ``joint_states`` topic: each usable message is one observation for ``step``.

    Args:
        node: the lifecycle node (its clock and logger).
        values: the node's parameter values (the same dict, kept current by the node).
        outputs: the node's publishers: the stream rule they publish for, the frame id of the steps.
        step: steps one observation and its stamp (:meth:`NodeInputs.process_observation`).
        reject: counts an input that cannot be used (:meth:`NodeInputs.reject`).
    """

    def __init__(self, node: LifecycleNode, values: dict[str, Any], outputs: NodePublishers,
                 step: Callable[[Any, int | None], None], reject: Callable[[InvalidInput], None]) -> None:
        self.node, self.values, self.outputs = node, values, outputs
        self.stream = outputs.stream
        self.step, self.reject = step, reject
        self.joints: JointInput | None = None  # configured (None: joint_fields in the message's order)

    def on_joint_state(self, msg: JointState) -> None:
        try:
            stamp = join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec)
        except StampRangeError as exc:
            self.reject(BadStamp(str(exc)))
            return
        fields = {f: np.asarray(getattr(msg, f)) for f in layout.JOINT_FIELDS}
        payload = "\0".join(msg.name).encode() + b"".join(v.tobytes() + b"|" for v in fields.values())
        if self.stream.repeats.seen_sample(layout.JOINT_STATES, stamp, payload):
            return  # the same sample sent twice (same header stamp and data): one step
        joints = self.joints or JointInput(self.values["joint_fields"], None, None)
        if joints.merger is not None and self._merge_refuses(stamp):
            return
        got = joints.observation(stamp, msg.name, fields)
        if got is None:  # joint_merge: another publisher's message, or a step lacking a joint (counted)
            silent = joints.silence_line()
            if silent is not None:
                self.node.get_logger().warning(silent)
            return
        if isinstance(got, str):
            self.reject(MalformedMessage(got))
            return
        self.outputs.frame_id = msg.header.frame_id
        with np.errstate(over="ignore"):  # beyond float32 -> inf, which the segmenter rejects
            self.step(got.astype(np.float32), stamp)

    def _merge_refuses(self, stamp_ns: int) -> bool:
        """``joint_merge``: a message of any publisher stamped more than ``max_stamp_lead`` ahead of the
        node's clock is rejected before it is merged (``future_stamp``), as a step would be: its values
        would otherwise look fresh to every step until the clock caught up."""
        limits = self.stream.limits
        if limits.max_lead_ns <= 0:
            return False
        now = self.node.get_clock().now().nanoseconds
        if classify_stamp(stamp_ns, None, now, jump_back_ns=0, max_lead_ns=limits.max_lead_ns) != "future":
            return False
        self.reject(FutureStamp(f"JointState stamped {stamp_ns} ns is more than max_stamp_lead="
                                f"{limits.max_stamp_lead} s ahead of the node's clock: not merged"))
        return True
