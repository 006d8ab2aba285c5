"""Other tools' file formats: MotionBenchMaker problems (import and export) and SRDF
generation. Our own scene YAML lives with the scene (``advocc_ros.model.scene``). No ROS."""
