"""ompn_node alone, for your own robot: a checkpoint, a params file and topic remappings.

    ros2 launch ompn_ros ompn_node.launch.py checkpoint:=/path/to/runs/mine/best \
        params_file:=/path/to/runs/mine/ompn_node.yaml namespace:=arm obs_topic:=/arm/features

``checkpoint`` is required (a directory with ``model.safetensors`` + ``config.json``, or an ensemble
directory).  ``params_file`` defaults to ``config/ompn_node.yaml`` (every parameter at its default);
``ompn_segment --tune --write-config`` writes one with detector settings measured for your checkpoint.
The input topics are remapped by argument: ``obs_topic`` (``Float32MultiArray``, with
``obs_source: array``) or ``joint_states_topic`` (``sensor_msgs/JointState``, with
``obs_source: joint_state``), the optional ``episode`` markers and ``sketch``, and the output
``cmd_action``.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    """The launch arguments, then ompn_node with the params file, the checkpoint and the remappings."""
    return LaunchDescription([
        DeclareLaunchArgument("checkpoint", description="checkpoint (or ensemble) directory"),
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([FindPackageShare("ompn_ros"), "config", "ompn_node.yaml"]),
            description="ompn_node parameters file",
        ),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("obs_topic", default_value="observation", description="observation input"),
        DeclareLaunchArgument(
            "joint_states_topic", default_value="joint_states", description="JointState input"
        ),
        DeclareLaunchArgument("episode_topic", default_value="episode", description="episode markers"),
        DeclareLaunchArgument("sketch_topic", default_value="sketch", description="episode sketch"),
        DeclareLaunchArgument("cmd_action_topic", default_value="cmd_action", description="action output"),
        Node(
            package="ompn_ros",
            executable="ompn_node",
            name="ompn_node",
            namespace=LaunchConfiguration("namespace"),
            output="screen",
            parameters=[
                LaunchConfiguration("params_file"),
                {
                    "checkpoint": ParameterValue(LaunchConfiguration("checkpoint"), value_type=str),
                    "use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                },
            ],
            remappings=[
                ("observation", LaunchConfiguration("obs_topic")),
                ("joint_states", LaunchConfiguration("joint_states_topic")),
                ("episode", LaunchConfiguration("episode_topic")),
                ("sketch", LaunchConfiguration("sketch_topic")),
                ("cmd_action", LaunchConfiguration("cmd_action_topic")),
            ],
        ),
    ])
