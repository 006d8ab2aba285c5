"""The audit: how few boxes make each planner fail one task, and where they go; its report.
No ROS."""
