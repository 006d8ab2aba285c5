"""Inverse kinematics: goal-region IK, goal sampling and the task's start configuration. No ROS."""
