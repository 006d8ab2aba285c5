"""ROS 2 nodes: thin shells over the core."""
