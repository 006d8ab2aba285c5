"""Metrics of planned trajectories (PSR, SMR, CMR, JDS, PT), time to first solution, evaluation
drivers, the audit (how few boxes make a planner fail one task), speed figures. No ROS.
"""

from advocc_ros.evaluation.metrics import (FAILURE_MODES, THRESHOLDS, MetricsConfig, TrialRecord,
                                           aggregate, densify, evaluate_planner, failure_mode,
                                           format_value, joint_deviation, min_clearance,
                                           min_manipulability, minimal_budgets,
                                           random_directions, trial_metrics)
from advocc_ros.evaluation.perf import benchmark_planning, machine
from advocc_ros.evaluation.audit import AuditConfig, run_audit
from advocc_ros.evaluation.audit_report import write_audit
from advocc_ros.evaluation.hardness import pt_ratio, time_summary

__all__ = [
    'AuditConfig', 'FAILURE_MODES', 'MetricsConfig', 'THRESHOLDS', 'TrialRecord', 'aggregate',
    'benchmark_planning', 'densify', 'evaluate_planner', 'failure_mode', 'format_value',
    'joint_deviation', 'machine', 'min_clearance', 'min_manipulability', 'minimal_budgets',
    'pt_ratio', 'random_directions', 'run_audit', 'time_summary', 'trial_metrics',
    'write_audit']
