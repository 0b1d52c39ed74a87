"""Craft (grid world): craft_sim + ompn_node + bag_recorder in one namespace.

    ros2 launch ompn_ros craft_sim.launch.py
    ros2 launch ompn_ros craft_sim.launch.py task:=makeaxe record:=false mode:=policy

``craft_sim`` publishes the step contract (docs/craft.md); ``ompn_node`` steps the shipped Craft
checkpoint on every observation and publishes ``cmd_action``, ``~/pi`` and ``~/boundary``;
``bag_recorder`` writes the sim topics to a rosbag2 (``record:=false`` leaves it out).  With
``mode:=policy`` the sim executes the node's ``cmd_action`` instead of the expert's action.
``ros2 launch ompn_ros craft_sim.launch.py --show-args`` lists the arguments
(:mod:`ompn_ros.ros.launch_sim`, shared with ``dial_sim.launch.py``).
"""

from ompn_ros.ros.launch_sim import sim_launch_description


def generate_launch_description():  # type: ignore[no-untyped-def]
    """10 steps per second, and the Craft task to run."""
    return sim_launch_description(
        "craft", rate="10.0", sim_arguments=[("task", "makebed", "Craft task name")]
    )
