"""The ROS 2 edge: the only shared code that imports rclpy or message packages.

Its modules are imported where they are used (``advocc_ros.ros.conversions``, ``.qos``, ...), so
that the stage packages and the CLI start without loading ROS.
"""
