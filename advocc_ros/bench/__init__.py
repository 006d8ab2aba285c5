"""The benchmark's bookkeeping: protocol, run plan, records and tables (no ROS).

Figures (``advocc_ros.bench.figures``, matplotlib) are imported where they are drawn.
"""

from advocc_ros.bench.protocol import (AttackSpec, BASELINE, baseline_table, BenchConfig,
                                       BenchError, budget_to_failure, cell_rows, check_run_config,
                                       IDENTITY_FIELDS, load_profile, log, MAX_BUDGET,
                                       METHOD_LABELS, plan_units, PLANNER_LABELS, progress_summary,
                                       RecordStore, run_lock, scene_label, table1, table2, table4,
                                       THRESHOLDS, Trial, trial_key, Unit)

__all__ = [
    'AttackSpec', 'BASELINE', 'baseline_table', 'BenchConfig', 'BenchError',
    'budget_to_failure', 'cell_rows', 'check_run_config', 'IDENTITY_FIELDS', 'load_profile',
    'log', 'MAX_BUDGET', 'METHOD_LABELS', 'plan_units', 'PLANNER_LABELS', 'progress_summary',
    'RecordStore', 'run_lock', 'scene_label', 'table1', 'table2', 'table4', 'THRESHOLDS',
    'Trial', 'trial_key', 'Unit']
