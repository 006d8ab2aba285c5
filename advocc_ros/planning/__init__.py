"""Our victims: OMPL planners to goal regions in a watched worker process, and witnesses. No ROS.

Import from the defining module (``advocc_ros.planning.types``, ``.worker``, ``.pool``, ...).
Goal sampling and the start configuration live in ``advocc_ros.kinematics.ik``.
"""
