"""ObservationSpec: validation (every error names the entry at fault), YAML form, layout and names."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data import messages as m
from ompn_ros.data.errors import ObservationSpecError
from ompn_ros.data.obs import FieldSpec, ObservationSpec, observation_layout

JS = "sensor_msgs/msg/JointState"
ARM = {
    "step_topic": "/arm1/joint_states",
    "tolerance_s": 0.02,
    "fields": [
        {"topic": "/arm1/joint_states", "type": JS, "field": "position", "names": ["j2", "j1"]},
        {"topic": "/arm1/gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 2},
        {"topic": "/arm1/wrench", "type": "geometry_msgs/msg/WrenchStamped", "field": "force"},
    ],
}


def test_dict_round_trip_and_outer_key() -> None:
    spec = ObservationSpec.from_dict({"observation": ARM})
    assert spec.step_topic == "/arm1/joint_states" and spec.tolerance_s == 0.02
    assert [f.field for f in spec.fields] == ["position", "data", "force"]
    assert spec.fields[0].names == ("j2", "j1")
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    assert spec.partner_topics == ("/arm1/gripper", "/arm1/wrench")
    assert spec.declared_dim() == 2 + 2 + 3


def test_yaml_file(tmp_path) -> None:
    yaml = pytest.importorskip("yaml")
    path = tmp_path / "obs.yaml"
    path.write_text(yaml.safe_dump({"observation": ARM}))
    assert ObservationSpec.from_yaml(path) == ObservationSpec.from_dict(ARM)
    bad = dict(ARM, fields=[dict(ARM["fields"][0], field="positon")])
    path.write_text(yaml.safe_dump({"observation": bad}))
    with pytest.raises(ObservationSpecError, match=r"obs\.yaml: fields\[0\]: .*'positon'"):
        ObservationSpec.from_yaml(path)


@pytest.mark.parametrize("type_name", ["JointState", "sensor_msgs/JointState", JS])
def test_type_spellings(type_name: str) -> None:
    assert FieldSpec("/js", type_name, "velocity").type == JS


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"fields": [{"topic": "/a", "type": JS, "field": "positon"}]}, r"fields\[0\].*no field 'positon'"),
        ({"fields": [{"topic": "/a", "type": JS, "field": "position", "nmes": []}]},
         r"fields\[0\]: unknown key \['nmes'\]"),
        ({"fields": [{"topic": "/a", "type": "std_msgs/msg/String", "field": "data"}]},
         r"fields\[0\].*std_msgs/msg/String: field path 'data' is a string"),
        ({"fields": [{"topic": "/a", "type": "Int8", "field": "data"}]},
         r"fields\[0\].*message type 'Int8' needs its package"),
        ({"fields": [{"topic": "/a", "type": JS, "field": "position", "size": 3}]},
         r"fields\[0\].*only MultiArray fields declare a size"),
        ({"fields": [{"topic": "/a", "type": "geometry_msgs/msg/PoseStamped", "field": "pose",
                      "names": ["x"]}]}, r"fields\[0\].*names are not allowed"),
        ({"fields": [{"topic": "/a", "type": JS, "field": "position", "names": ["j1", "j1"]}]},
         r"fields\[0\].*duplicates"),
        ({"fields": [{"topic": "/a", "type": JS}]}, r"fields\[0\]\.field is missing"),
        ({"tolerance": 1.0}, r"observation: unknown key \['tolerance'\]"),
        ({"tolerance_s": -1.0}, r"tolerance_s must be a finite number >= 0"),
        ({"wait_s": float("inf")}, r"wait_s must be a finite number >= 0"),
        ({"stamp": "log"}, r"stamp must be 'header' or 'receive'"),
        ({"step_topic": "/nowhere"}, r"step_topic '/nowhere' gives no field"),
        ({"fields": []}, r"at least one field"),
    ],
)
def test_errors_name_the_entry(change: dict, match: str) -> None:
    base = {"step_topic": "/a", "fields": [{"topic": "/a", "type": JS, "field": "position"}]}
    with pytest.raises(ObservationSpecError, match=match):
        ObservationSpec.from_dict({**base, **change})


def test_topic_with_two_types_and_repeated_field_are_rejected() -> None:
    two_types = [{"topic": "/a", "type": JS, "field": "position"},
                 {"topic": "/a", "type": "std_msgs/msg/Float64", "field": "data"}]
    with pytest.raises(ObservationSpecError, match=r"fields\[1\].*topic '/a' is sensor_msgs/msg/JointState"):
        ObservationSpec.from_dict({"step_topic": "/a", "fields": two_types})
    repeated = [{"topic": "/a", "type": JS, "field": "position"}] * 2
    with pytest.raises(ObservationSpecError, match=r"fields\[1\]: field 'position' of '/a' is already"):
        ObservationSpec.from_dict({"step_topic": "/a", "fields": repeated})


def test_namespace_and_type_check() -> None:
    spec = ObservationSpec.from_dict({"step_topic": "joint_states", "fields": [
        {"topic": "joint_states", "type": JS, "field": "position"},
        {"topic": "/tool/wrench", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"}]})
    ns = spec.with_namespace("/arm1")
    assert ns.step_topic == "/arm1/joint_states" and ns.fields[1].topic == "/tool/wrench"
    problems = ns.check_types({"/arm1/joint_states": JS, "/tool/wrench": "std_msgs/msg/Float32MultiArray"})
    assert problems == ["topic '/tool/wrench' has type std_msgs/msg/Float32MultiArray, the observation "
                        "spec expects geometry_msgs/msg/WrenchStamped"]


def test_layout_from_first_messages() -> None:
    spec = ObservationSpec.from_dict({"step_topic": "/js", "fields": [
        {"topic": "/js", "type": JS, "field": "velocity"},
        {"topic": "/g", "type": "std_msgs/msg/Float64MultiArray", "field": "data"},
        {"topic": "/p", "type": "geometry_msgs/msg/PoseStamped", "field": "orientation"}]})
    assert spec.declared_dim() is None
    with pytest.raises(ValueError, match=r"topic '/js'.*not declared"):
        observation_layout(spec)
    js = m.serialize(m.joint_state(5, ["a", "b", "c"], [0, 0, 0], [1, 2, 3]))
    g = m.serialize(m.msg_class("std_msgs/msg/Float64MultiArray")(
        layout=m.msg_class("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0), data=np.zeros(2)))
    dim, names = observation_layout(spec, {"/js": js, "/g": g})
    assert dim == 3 + 2 + 4
    assert names == ("js/velocity/a", "js/velocity/b", "js/velocity/c", "g/data/0", "g/data/1",
                     "p/orientation/x", "p/orientation/y", "p/orientation/z", "p/orientation/w")


def test_from_param_inline_or_path_and_reader_file(tmp_path) -> None:
    yaml = pytest.importorskip("yaml")
    inline = ObservationSpec.from_param(yaml.safe_dump(ARM, default_flow_style=True).replace("\n", " "))
    assert inline == ObservationSpec.from_dict(ARM)
    path = tmp_path / "reader.yaml"  # an observation block among other (reader) keys
    path.write_text(yaml.safe_dump({"tolerance": 5.0, "observation": ARM}))
    assert ObservationSpec.from_param(str(path)) == inline
    with pytest.raises(ObservationSpecError, match="cannot read observation spec"):
        ObservationSpec.from_param(str(tmp_path / "missing.yaml"))
    with pytest.raises(ObservationSpecError, match="empty"):
        ObservationSpec.from_param("  ")


def test_single_topic_is_the_sims_observation() -> None:
    spec = ObservationSpec.single_topic("observation", 39)
    assert spec.declared_dim() == 39 and spec.partner_topics == ()
    assert spec.fields[0].type == "std_msgs/msg/Float32MultiArray"


def test_a_reader_spec_file_serves_the_node_too() -> None:
    """ompn_node's observation_spec accepts the reader spec's assemble: block: one YAML, one rule."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    from_reader = ObservationSpec.from_param(str(root / "config" / "reader_dial_robot.yaml"))
    assert from_reader.step_topic == "jaco/joint_states"
    assert [f.field for f in from_reader.fields] == ["position", "velocity"]
