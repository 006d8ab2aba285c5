"""Metrics of planned trajectories (PSR, SMR, CMR, JDS, PT), evaluation drivers, speed figures.
No ROS.
"""

from advocc_ros.evaluation.metrics import (FAILURE_MODES, MetricsConfig, TrialRecord, aggregate,
                                           densify, evaluate_planner, failure_mode, format_value,
                                           joint_deviation, min_clearance, min_manipulability,
                                           random_directions, trial_metrics)
from advocc_ros.evaluation.perf import benchmark_planning, machine

__all__ = [
    'FAILURE_MODES', 'MetricsConfig', 'TrialRecord', 'aggregate', 'benchmark_planning',
    'densify', 'evaluate_planner', 'failure_mode', 'format_value', 'joint_deviation', 'machine',
    'min_clearance', 'min_manipulability', 'random_directions', 'trial_metrics']
