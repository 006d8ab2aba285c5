"""Benchmark bookkeeping (paper §V; docs/metrics.md): protocol, run plan, records, tables. No ROS.

The orchestrator (``advocc_ros.orchestrator``) drives real nodes; everything it needs to decide
*what* to run and to turn results into the paper's tables lives here, so it can be tested on
hand-made records:

- ``BenchConfig`` (``protocol``): one protocol (a profile of ``config/bench.yaml`` plus
  command-line overrides).
- ``plan_units`` (``protocol``): the run plan of units (one planning scene to inject and the
  trials to run in it).
- ``RecordStore`` (``records``): per-trial JSON lines, appended with flush + fsync, so a re-run
  resumes exactly.
- ``cell_rows`` / ``table1`` / ``table2`` / ``table4`` (``tables``): the paper's Tables I, II
  and IV as Markdown and CSV.
- ``write_report`` (``report``): a run folder's tables, figures and summary.

``figures`` (matplotlib) is imported where figures are drawn.
"""

from advocc_ros.bench.protocol import (AttackSpec, BASELINE, BenchConfig, BenchError,
                                       IDENTITY_FIELDS, MAX_BUDGET, METHOD_LABELS, PLANNER_LABELS,
                                       Trial, Unit, load_profile, plan_units,
                                       scene_label, trial_key, variation_scenes)
from advocc_ros.bench.records import RecordStore, check_run_config, progress_summary, run_lock
from advocc_ros.bench.tables import baseline_table, cell_rows, table1, table2, table4
from advocc_ros.bench.report import write_report

__all__ = [
    'AttackSpec', 'BASELINE', 'BenchConfig', 'BenchError', 'IDENTITY_FIELDS', 'MAX_BUDGET',
    'METHOD_LABELS', 'PLANNER_LABELS', 'RecordStore', 'Trial', 'Unit',
    'baseline_table', 'cell_rows', 'check_run_config', 'load_profile',
    'plan_units', 'progress_summary', 'run_lock', 'scene_label', 'table1', 'table2', 'table4',
    'trial_key', 'variation_scenes', 'write_report']
