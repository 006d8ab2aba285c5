"""advocc_ros: planner-agnostic adversarial obstacles for tolerance-aware manipulation.

The core (robot, scene, collision, heatmap, attack, planning, metrics, ...) never imports rclpy;
the ROS 2 nodes in ``advocc_ros.nodes`` are thin shells over it.
"""

__version__ = '0.1.0'
