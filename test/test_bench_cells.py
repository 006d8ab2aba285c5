"""``cells.csv``, the bench's one row per cell that a study's results file copies (no ROS)."""

import csv
import json

from advocc_ros.bench import BASELINE, BenchConfig, RecordStore, trial_key
from advocc_ros.bench.tables import CELL_COLUMNS
from advocc_ros.cli import main


def _rec(method, budget, trial, status, first=None, goal_found=None, unix=1_795_700_000.0):
    rec = {'key': trial_key('table_pick', 'rrtconnect', method, budget, trial),
           'scene': 'table_pick', 'planner': 'rrtconnect', 'method': method, 'budget': budget,
           'trial': trial, 'seed': trial, 'success': status == 'SUCCESS', 'status': status,
           'planning_time_s': first or 5.0, 'time_budget_s': 5.0, 'first_solution_s': first,
           'min_manipulability': 0.05 if first else None, 'jds_rad': 1.0 if first else None,
           'min_clearance_rad': 0.02 if first else None, 'unix': unix + 60 * trial}
    if goal_found is not None:
        rec['goal_found'] = goal_found
    return rec


def test_cells_csv_holds_each_cell_of_the_run(tmp_path):
    """PSR, PSR given goals and the trials without a goal, failure modes, the attacks' goal
    share and verdicts, median first solution, PT ratio and trial times, one row per cell;
    ``advocc bench --report-only`` writes it under the run's own settings (its config.json),
    whatever the profile, with every cell of the records."""
    run = tmp_path / 'grid_seed7'
    cfg = BenchConfig(scenes=('table_pick',), planners=('rrtconnect',), methods=('task',),
                      budgets=(10,), trials=4, time_budget_s=5.0, seed=7)
    store = RecordStore(run / 'records.jsonl')
    for k, first in enumerate((0.2, 0.2, 0.4, 0.4)):
        store.append(_rec(BASELINE, 0, k, 'SUCCESS', first))
    for k, (status, first, found) in enumerate((('SUCCESS', 1.6, True),
                                                ('GOAL_IN_COLLISION', None, False),
                                                ('TIMED_OUT', None, True),
                                                ('GOAL_IN_COLLISION', None, False))):
        store.append({**_rec('task', 10, k, status, first, found), 'commit': f'c{k % 2}',
                      'dirty': k == 3, 'host': 'h', 'cpu': 'AMD EPYC', 'load_1min': 1.5 + k})
    store.append(_rec('task', 3, 0, 'SUCCESS', 0.5, True))  # a budget the settings dropped
    attacks = run / 'attacks' / 'table_pick'
    attacks.mkdir(parents=True)
    for i, (share, verdict) in enumerate(((0.25, 'certified'), (0.5, 'unknown'))):
        (attacks / f'task_b10_v{i}.yaml').write_text(
            f'method: task\nbudget: 10\ngoal_valid_fraction: {share}\n'
            f'solvable: {{verdict: {verdict}}}\nobjects: []\n')
    (run / 'config.json').write_text(json.dumps({'config': cfg.to_data()}))
    assert main(['bench', '--profile', 'quick', '--report-only', '--out', str(run)]) == 0
    with open(run / 'cells.csv', newline='') as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == CELL_COLUMNS and len(rows) == 3
    base, dropped, task = rows
    assert (dropped['budget'], dropped['psr_percent'], dropped['pt_ratio']) == \
        ('3', '100', '1.66667')
    assert (base['run'], base['seed'], base['method'], base['budget']) == \
        ('grid_seed7', '7', BASELINE, '0')
    assert (base['psr_percent'], base['first_solution_median_s'], base['pt_ratio'],
            base['goal_valid_fraction'], base['certified']) == ('100', '0.3', '1', '1', '')
    assert (task['trials'], task['psr_percent'], task['psr_given_goals_percent'],
            task['no_goal_found']) == ('4', '25', '50', '2')
    assert (task['goal_not_sampled'], task['timed_out'], task['internal_errors']) == \
        ('2', '1', '0')
    # median first solution: failures at the 5 s budget, (1.6 + 5) / 2 over 0.3 unattacked
    assert (task['first_solution_median_s'], task['pt_ratio']) == ('5', '16.6667')
    assert (task['goal_valid_fraction'], task['certified'], task['goal_blocked'],
            task['unknown']) == ('0.375', '1', '0', '1')
    assert (task['first_trial_utc'], task['last_trial_utc']) == \
        ('2026-11-26 13:33 UTC', '2026-11-26 13:36 UTC')
    # what made them: each commit once, dirty when one was, the highest load; empty when the
    # records name nothing (made before the bench recorded it)
    assert (task['commit'], task['dirty'], task['host'], task['cpu'], task['load_1min_max']) == \
        ('c0 c1', '1', 'h', 'AMD EPYC', '4.5')
    assert (base['commit'], base['dirty'], base['host'], base['load_1min_max']) == ('', '', '', '')
