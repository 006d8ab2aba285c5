"""Metrics of planned trajectories (PSR, SMR, CMR, JDS, PT), time to first solution, how trials
ended, the evaluation driver, speed figures and what made a record (provenance). No ROS.

Import from the defining module (``advocc_ros.evaluation.metrics``, ``.outcomes``, ...). The
audit lives in ``advocc_ros.audit``, the 3D page in ``advocc_ros.view``.
"""
