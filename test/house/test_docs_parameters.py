"""docs/parameters.md is generated from the nodes' own parameter tables, so it cannot drift.

Regenerate it with ``.venv/bin/python test/house/test_docs_parameters.py`` after changing a ParamSpec.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "parameters.md"
HEADER = """# Node parameters

Generated from the nodes' `ParamSpec` tables (`python test/house/test_docs_parameters.py`; a test keeps it
current). *applies*: `live` = from the next step, `configure` = refused while the node is active
(deactivate, clean up, set it, configure), `startup` = read-only after start-up. A bad value stops a
node at start-up with one line naming the parameter and exit code 2; at run time it is refused with
the reason.
"""


def render() -> str:
    sys.path.insert(0, str(ROOT))
    from ompn_ros.nodes import bag_recorder, dds_probe, episode_monitor, ompn_node_params
    from ompn_ros.ros.params import markdown_table
    from sim_nodes.craft.node import CRAFT_PARAMS
    from sim_nodes.dial.node import DIAL_PARAMS
    from sim_nodes.ros_common import COMMON_PARAMS

    sections = [
        ("ompn_node", ompn_node_params.SPECS),
        ("craft_sim and dial_sim (common)", COMMON_PARAMS),
        ("craft_sim", CRAFT_PARAMS),
        ("dial_sim (its `rate` replaces the common one)", DIAL_PARAMS),
        ("bag_recorder", bag_recorder.PARAMS),
        ("episode_monitor", episode_monitor.PARAMS.specs.values()),
        ("smoke_talker", dds_probe.TALKER_PARAMS.specs.values()),
        ("smoke_listener", dds_probe.LISTENER_PARAMS.specs.values()),
    ]
    body = "\n\n".join(f"## {title}\n{markdown_table(specs)}" for title, specs in sections)
    return f"{HEADER}\n{body}\n"


def test_parameters_doc_is_current() -> None:
    pytest.importorskip("rclpy")
    assert DOC.read_text() == render(), \
        "docs/parameters.md is stale: run python test/house/test_docs_parameters.py"


def test_defaults_declared_by_type_read_as_unset() -> None:
    """Before: array parameters declared by their type printed as `Type.STRING_ARRAY` (``<Type.STRING_ARRAY:
    9>`` in ``--help``)."""
    pytest.importorskip("rclpy")
    from ompn_ros.ros.params import help_text
    from sim_nodes.dial.node import DIAL_PARAMS
    from sim_nodes.ros_common import COMMON_PARAMS

    assert "Type." not in render()
    assert "| `human` | `unset (string array)` |" in render()
    text = help_text("dial_sim", "", [*COMMON_PARAMS, *DIAL_PARAMS])
    assert "<Type" not in text and "human (default unset (string array); startup)" in text
    assert "sketch (default unset (integer array); startup)" in text


if __name__ == "__main__":
    DOC.write_text(render())
    print(f"wrote {DOC}")
