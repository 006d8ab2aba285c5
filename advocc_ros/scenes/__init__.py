"""New scenes from a scene: seeded variations (MotionBenchMaker-style) and simulated sensing.
No ROS."""
