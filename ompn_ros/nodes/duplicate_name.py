"""Two nodes with one fully qualified name: both would answer the same services and write the same
``/diagnostics`` status, so their outputs double and their counters mix.  ROS 2 lets both start;
``ompn_node`` counts the nodes of its own name on the graph from its health timer and says so once
(a warning line and a ``/diagnostics`` status; :meth:`OMPNNode._health_tick`)."""

from __future__ import annotations

from typing import Any

__all__ = ["duplicate_line", "same_name_count"]


def same_name_count(node: Any) -> int:
    """Nodes on the graph named like ``node`` (itself included; 1 when the graph cannot be read)."""
    try:
        names = node.get_node_names_and_namespaces()
    except Exception:  # the graph is unavailable while the context shuts down
        return 1
    name, namespace = node.get_name(), node.get_namespace()
    return max(1, sum(1 for n, ns in names if n == name and ns == namespace))


def duplicate_line(full_name: str, others: int) -> str:
    """The warning when ``others`` more nodes share ``full_name``."""
    return (f"{others} other node(s) named '{full_name}' on the graph: outputs and /diagnostics counters "
            "of both are mixed; give each a unique name (--ros-args -r __node:=NAME or -r __ns:=/NS)")
