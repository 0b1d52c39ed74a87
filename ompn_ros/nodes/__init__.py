"""ROS 2 nodes (the only place in ompn_ros that imports rclpy)."""
