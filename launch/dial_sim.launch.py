"""Dial (MuJoCo JACO arm): dial_sim + ompn_node + bag_recorder in one namespace.

    ros2 launch ompn_ros dial_sim.launch.py
    ros2 launch ompn_ros dial_sim.launch.py namespace:=sim1 record:=false mode:=policy

``dial_sim`` publishes the step contract (docs/dial.md); ``ompn_node`` steps the shipped Dial
checkpoint on every observation and publishes ``cmd_action``, ``~/pi`` and ``~/boundary``;
``bag_recorder`` writes the sim topics to a rosbag2 (``record:=false`` leaves it out).  With
``mode:=policy`` the sim executes the node's ``cmd_action`` instead of the expert's action.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def _text(argument: str) -> ParameterValue:
    """A string parameter from a launch argument (a plain substitution would be parsed as YAML: '' fails)."""
    return ParameterValue(LaunchConfiguration(argument), value_type=str)


def generate_launch_description() -> LaunchDescription:
    """The launch arguments, then the three nodes (the recorder only with ``record:=true``)."""
    namespace = LaunchConfiguration("namespace")
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    record = LaunchConfiguration("record")
    share = FindPackageShare("ompn_ros")
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="namespace of all three nodes"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("record", default_value="true", description="run bag_recorder (true|false)"),
        DeclareLaunchArgument(
            "bag", default_value="", description="bag directory to write ('' = bags/rec_<UTC time>)"
        ),
        DeclareLaunchArgument("storage", default_value="mcap", description="bag storage: mcap | sqlite3"),
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([share, "config", "ompn_node_dial.yaml"]),
            description="ompn_node parameters (domain and the measured detector settings)",
        ),
        DeclareLaunchArgument(
            "checkpoint", default_value="", description="checkpoint directory ('' = the shipped Dial one)"
        ),
        DeclareLaunchArgument("mode", default_value="expert", description="sim actions: expert | policy"),
        DeclareLaunchArgument(
            "rate", default_value="25.0", description="sim steps per second (25 = real time)"
        ),
        DeclareLaunchArgument("seed", default_value="0", description="sim base seed"),
        DeclareLaunchArgument("episodes", default_value="0", description="sim episodes (0 = forever)"),
        Node(
            package="ompn_ros",
            executable="ompn_node",
            name="ompn_node",
            namespace=namespace,
            output="screen",
            parameters=[
                LaunchConfiguration("params_file"),
                {"checkpoint": _text("checkpoint"), "use_sim_time": use_sim_time},
            ],
        ),
        Node(
            package="ompn_ros",
            executable="bag_recorder",
            name="bag_recorder",
            namespace=namespace,
            output="screen",
            condition=IfCondition(record),
            parameters=[
                PathJoinSubstitution([share, "config", "bag_recorder.yaml"]),
                {"output": _text("bag"), "storage": _text("storage"), "use_sim_time": use_sim_time},
            ],
        ),
        Node(
            package="ompn_ros",
            executable="dial_sim",
            name="dial_sim",
            namespace=namespace,
            output="screen",
            parameters=[{
                "mode": _text("mode"),
                "rate": ParameterValue(LaunchConfiguration("rate"), value_type=float),
                "seed": ParameterValue(LaunchConfiguration("seed"), value_type=int),
                "episodes": ParameterValue(LaunchConfiguration("episodes"), value_type=int),
                # hold the first episode until ompn_node (and the recorder) subscribe to observation
                "wait_for_subscribers": ParameterValue(
                    PythonExpression(["2 if '", record, "' == 'true' else 1"]), value_type=int
                ),
                "wait_topics": ["observation"],
                "use_sim_time": use_sim_time,
            }],
        ),
    ])
