"""The one parameter helper of every node: rules, descriptors and when a change may apply."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")
from rclpy.parameter import Parameter

from ompn_ros.ros.params import ParameterError, ParamSpec, ParamTable

SPECS = (
    ParamSpec("high", 0.5, "threshold", float_range=(0.0, 1.0), apply="live"),
    ParamSpec("checkpoint", "", "model directory", apply="configure"),
    ParamSpec("fields", ["position"], "JointState arrays", choices=("position", "velocity", "effort")),
    ParamSpec("depth", 10, "queue depth", int_range=(1, 100),
              check=lambda v: "must be even" if v % 2 else None),
)  # fmt: skip


def test_rules_name_the_parameter_and_the_allowed_values() -> None:
    table = ParamTable(SPECS)
    with pytest.raises(ParameterError, match=r"invalid parameter 'high': 2.0 is outside \[0.0, 1.0\]"):
        table.specs["high"].validate(2.0)
    with pytest.raises(ParameterError, match=r"'fields'.*not one of \['position', 'velocity', 'effort'\]"):
        table.specs["fields"].validate(["position", "torque"])
    with pytest.raises(ParameterError, match="'depth': must be even"):
        table.specs["depth"].validate(7)
    table.specs["fields"].validate(["velocity", "effort"])
    table.specs["depth"].validate(8)


def test_descriptors_carry_ranges_choices_and_read_only() -> None:
    table = ParamTable(SPECS)
    high = table.specs["high"].descriptor()
    assert high.floating_point_range[0].to_value == 1.0 and not high.read_only
    assert table.specs["depth"].descriptor().read_only  # startup parameters are read-only
    assert "velocity" in table.specs["fields"].descriptor().additional_constraints


def test_changes_configure_parameters_refused_while_active_with_the_way_out() -> None:
    table = ParamTable(SPECS)
    change = [Parameter("checkpoint", value="/models/b")]
    assert table.check_changes(change, active=False).successful
    refused = table.check_changes(change, active=True)
    assert not refused.successful and "deactivate" in refused.reason and "'checkpoint'" in refused.reason
    live = table.check_changes([Parameter("high", value=0.3)], active=True)
    assert live.successful
    bad = table.check_changes([Parameter("high", value=1.5)], active=True)
    assert not bad.successful and "'high'" in bad.reason
    assert table.check_changes([Parameter("use_sim_time", value=True)], active=True).successful


def test_a_parameter_listed_twice_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="'high' is listed twice"):
        ParamTable((SPECS[0], SPECS[0]))


def test_the_shipped_parameter_file_lists_every_parameter_with_its_default() -> None:
    """config/ompn_node.yaml says it lists all parameters with their defaults; before, 9 of 34 were
    missing."""
    import yaml

    from ompn_ros.nodes.ompn_node_params import SPECS

    path = Path(__file__).resolve().parents[2] / "config" / "ompn_node.yaml"
    listed = yaml.safe_load(path.read_text())["/**/ompn_node"]["ros__parameters"]
    declared = {spec.name: spec.default for spec in SPECS}
    assert sorted(set(declared) - set(listed)) == [], "missing from config/ompn_node.yaml"
    assert sorted(set(listed) - set(declared)) == [], "not a parameter of ompn_node"
    assert {name: value for name, value in listed.items() if value != declared[name]} == {}
