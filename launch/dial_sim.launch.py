"""Dial (MuJoCo JACO arm): dial_sim + ompn_node + bag_recorder in one namespace.

    ros2 launch ompn_ros dial_sim.launch.py
    ros2 launch ompn_ros dial_sim.launch.py namespace:=sim1 record:=false mode:=policy

``dial_sim`` publishes the step contract (docs/dial.md); ``ompn_node`` steps the shipped Dial
checkpoint on every observation and publishes ``cmd_action``, ``~/pi`` and ``~/boundary``;
``bag_recorder`` writes the sim topics to a rosbag2 (``record:=false`` leaves it out).  With
``mode:=policy`` the sim executes the node's ``cmd_action`` instead of the expert's action.
``ros2 launch ompn_ros dial_sim.launch.py --show-args`` lists the arguments
(:mod:`ompn_ros.ros.launch_sim`, shared with ``craft_sim.launch.py``).
"""

from ompn_ros.ros.launch_sim import sim_launch_description


def generate_launch_description():  # type: ignore[no-untyped-def]
    """25 steps per second: the arm in real time."""
    return sim_launch_description("dial", rate="25.0")
