"""Metrics of planned trajectories (PSR, SMR, CMR, JDS, PT), evaluation drivers, speed figures."""

from advocc_ros.evaluation.metrics import (aggregate, densify, evaluate_planner, format_value,
                                           joint_deviation, MetricsConfig, min_clearance,
                                           min_manipulability, random_directions, trial_metrics,
                                           TrialRecord)
from advocc_ros.evaluation.perf import (benchmark_planning, machine)

__all__ = [
    'aggregate', 'benchmark_planning', 'densify', 'evaluate_planner', 'format_value',
    'joint_deviation', 'machine', 'MetricsConfig', 'min_clearance', 'min_manipulability',
    'random_directions', 'trial_metrics', 'TrialRecord']
