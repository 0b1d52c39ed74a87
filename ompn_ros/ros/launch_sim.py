"""The one launch description of the simulators: ``<domain>_sim`` + ``ompn_node`` + ``bag_recorder``.

``launch/dial_sim.launch.py`` and ``launch/craft_sim.launch.py`` each call :func:`sim_launch_description`
with what differs between the two domains: the default step rate and the sim's own arguments (Craft's
``task``).  Everything else (the arguments, the three nodes, their parameters) is written once here.

The ``launch`` and ``launch_ros`` packages come with a ROS 2 install, not with this package's pip
requirements, so they are imported when a launch file asks for a description, not when this module is
imported.  ``test/ros/test_launch_files.py`` runs the launch files against stand-ins of those packages and
resolves every name they give in a colcon install space.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

Domain = Literal["dial", "craft"]


def _param(argument: str, value_type: type = str) -> Any:
    """A parameter of ``value_type`` from a launch argument (a bare substitution is parsed as YAML, where
    '' is null and fails)."""
    from launch.substitutions import LaunchConfiguration
    from launch_ros.parameter_descriptions import ParameterValue

    return ParameterValue(LaunchConfiguration(argument), value_type=value_type)


def _arguments(domain: Domain, rate: str, sim_arguments: Sequence[tuple[str, str, str]]) -> list[Any]:
    """The launch arguments: the nodes' shared ones, then the sim's own (``sim_arguments``)."""
    from launch.actions import DeclareLaunchArgument
    from launch.substitutions import PathJoinSubstitution
    from launch_ros.substitutions import FindPackageShare

    params_file = PathJoinSubstitution([FindPackageShare("ompn_ros"), "config", f"ompn_node_{domain}.yaml"])
    declared: list[tuple[str, Any, str]] = [
        ("namespace", "", "namespace of all three nodes"),
        ("use_sim_time", "false", "follow /clock"),
        ("record", "true", "run bag_recorder (true|false)"),
        ("bag", "", "bag directory to write ('' = bags/rec_<UTC time>)"),
        ("storage", "mcap", "bag storage: mcap | sqlite3"),
        ("params_file", params_file, "ompn_node parameters (domain and the measured detector settings)"),
        ("checkpoint", "", f"checkpoint directory ('' = the shipped {domain.title()} one)"),
        ("mode", "expert", "sim actions: expert | policy"),
        ("rate", rate, "sim steps per second"),
        ("seed", "0", "sim base seed"),
        ("episodes", "0", "sim episodes (0 = forever)"),
        *sim_arguments,
    ]
    return [DeclareLaunchArgument(name, default_value=default, description=text)
            for name, default, text in declared]


def sim_launch_description(
    domain: Domain, rate: str, sim_arguments: Sequence[tuple[str, str, str]] = ()
) -> Any:
    """``<domain>_sim``, ``ompn_node`` (the domain's params file and shipped checkpoint) and, with
    ``record:=true``, ``bag_recorder``, all in ``namespace``.

    Args:
        domain: ``'dial'`` or ``'craft'``: names the sim executable and ``config/ompn_node_<domain>.yaml``.
        rate: the default of the ``rate`` argument (sim steps per second).
        sim_arguments: ``(name, default, description)`` of further launch arguments, each passed to the
            sim as the string parameter of that name.
    """
    from launch import LaunchDescription
    from launch.conditions import IfCondition
    from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
    from launch_ros.actions import Node
    from launch_ros.parameter_descriptions import ParameterValue
    from launch_ros.substitutions import FindPackageShare

    namespace, record = LaunchConfiguration("namespace"), LaunchConfiguration("record")
    use_sim_time = _param("use_sim_time", bool)
    sim_parameters = {
        "mode": _param("mode"),
        "rate": _param("rate", float),
        "seed": _param("seed", int),
        "episodes": _param("episodes", int),
        **{name: _param(name) for name, _, _ in sim_arguments},
        # hold the first episode until ompn_node (and the recorder) subscribe to observation
        "wait_for_subscribers": ParameterValue(
            PythonExpression(["2 if '", record, "' == 'true' else 1"]), value_type=int
        ),
        "wait_topics": ["observation"],
        "use_sim_time": use_sim_time,
    }
    recorder_file = PathJoinSubstitution([FindPackageShare("ompn_ros"), "config", "bag_recorder.yaml"])
    # The sim publishes its time on 'clock' in the namespace (sim_nodes.ros_common); every node of
    # this launch follows that one under use_sim_time, never another namespace's sim.
    own_clock = [("/clock", "clock")]
    return LaunchDescription([
        *_arguments(domain, rate, sim_arguments),
        Node(package="ompn_ros", executable="ompn_node", name="ompn_node", namespace=namespace,
             output="screen", remappings=own_clock, parameters=[
                 LaunchConfiguration("params_file"),
                 {"checkpoint": _param("checkpoint"), "use_sim_time": use_sim_time},
             ]),
        Node(package="ompn_ros", executable="bag_recorder", name="bag_recorder", namespace=namespace,
             output="screen", condition=IfCondition(record), remappings=own_clock,
             parameters=[recorder_file, {"output": _param("bag"), "storage": _param("storage"),
                                         "use_sim_time": use_sim_time}]),
        Node(package="ompn_ros", executable=f"{domain}_sim", name=f"{domain}_sim", namespace=namespace,
             output="screen", remappings=own_clock, parameters=[sim_parameters]),
    ])
