"""Metrics of planned trajectories (PSR, SMR, CMR, JDS, PT), time to first solution, how trials
ended, evaluation drivers, the audit (how few boxes make a planner fail one task), speed
figures. No ROS.
"""

from advocc_ros.evaluation.budgets import THRESHOLDS, minimal_budgets
from advocc_ros.evaluation.metrics import (MetricsConfig, PathInCollision, TrialRecord,
                                           aggregate, densify, format_value, joint_deviation,
                                           min_clearance, min_manipulability, random_directions,
                                           trial_metrics)
from advocc_ros.evaluation.outcomes import FAILURE_MODES, outcome, record_outcome
from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.evaluation.perf import benchmark_planning, machine
from advocc_ros.evaluation.audit import AuditConfig, run_audit
from advocc_ros.evaluation.audit_report import write_audit
from advocc_ros.evaluation.hardness import pt_ratio, time_summary

__all__ = [
    'AuditConfig', 'FAILURE_MODES', 'MetricsConfig', 'PathInCollision', 'THRESHOLDS',
    'TrialRecord', 'aggregate', 'benchmark_planning', 'densify', 'evaluate_planner',
    'format_value', 'joint_deviation', 'machine', 'min_clearance', 'min_manipulability',
    'minimal_budgets', 'outcome', 'pt_ratio', 'random_directions', 'record_outcome',
    'run_audit', 'time_summary', 'trial_metrics', 'write_audit']
