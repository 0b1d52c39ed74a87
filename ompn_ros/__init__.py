"""ompn_ros."""
