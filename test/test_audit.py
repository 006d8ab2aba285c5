"""The audit: minimal budgets from PSR curves, and one small audit end to end on table_pick."""

import json

import pytest

from advocc_ros.audit.audit import AuditConfig, minimal_budgets
from advocc_ros.evaluation.outcomes import FAILURE_MODES


def test_minimal_budgets_monotone_curve():
    psr = {'rrtconnect': [1.0, 0.9, 0.5, 0.2, 0.0]}
    out = minimal_budgets(psr)
    assert list(out) == ['0.8', '0.6', '0.4', '0.2', '0.0']
    assert {t: row['rrtconnect'] for t, row in out.items()} == \
        {'0.8': 2, '0.6': 2, '0.4': 3, '0.2': 3, '0.0': 4}


def test_minimal_budgets_never_reaching_is_none():
    out = minimal_budgets({'prmstar': [1.0, 0.9, 0.7], 'bkpiece1': [1.0, 0.5, 0.3]})
    assert out['0.8'] == {'prmstar': 2, 'bkpiece1': 1}
    assert out['0.6'] == {'prmstar': None, 'bkpiece1': 1}
    assert out['0.2'] == {'prmstar': None, 'bkpiece1': None}
    assert out['0.0'] == {'prmstar': None, 'bkpiece1': None}
    assert json.loads(json.dumps(out))['0.0']['prmstar'] is None  # JSON null


def test_minimal_budgets_non_monotone_takes_the_first_crossing():
    psr = {'rrtconnect': [0.9, 0.3, 0.7, 0.0, 0.4]}
    out = minimal_budgets(psr, thresholds=(0.8, 0.5, 0.2, 0.0))
    assert {t: row['rrtconnect'] for t, row in out.items()} == \
        {'0.8': 1, '0.5': 1, '0.2': 3, '0.0': 3}


def test_minimal_budgets_edge_cases():
    assert minimal_budgets({'rrt': [0.8]})['0.8'] == {'rrt': 0}  # "<=", at m = 0
    assert minimal_budgets({'rrt': [1.0, None, 0.0]})['0.0'] == {'rrt': 2}  # None: not measured
    assert minimal_budgets({'rrt': []})['0.0'] == {'rrt': None}
    assert minimal_budgets({}) == {t: {} for t in ('0.8', '0.6', '0.4', '0.2', '0.0')}


def test_audit_config_rejects_bad_values():
    for bad in (dict(trials=0), dict(max_budget=0), dict(time_budget_s=0), dict(workers=0),
                dict(planners=())):
        with pytest.raises(ValueError):
            AuditConfig(**bad)


def test_audit_config_target_and_prefixes():
    for bad in (dict(target_psr=float('nan')), dict(target_psr=-0.1), dict(target_psr=1.5),
                dict(prefixes=(-1,)), dict(prefixes=(1.5,)), dict(prefixes=(True,)),
                dict(prefixes=(6,))):
        with pytest.raises(ValueError, match='target PSR|prefixes'):
            AuditConfig(max_budget=5, **bad)
    cfg = AuditConfig(max_budget=5, prefixes=(5, 3, 3), target_psr=0.25)
    assert cfg.prefixes == (0, 3, 5)  # the unattacked control always, sorted, once
    assert cfg.thresholds() == (0.8, 0.6, 0.4, 0.25, 0.2, 0.0)
    assert AuditConfig(target_psr=0.2).thresholds() == AuditConfig().thresholds()
    assert AuditConfig().target_psr is None and AuditConfig().prefixes is None


def test_audit_command_errors(tmp_path, capsys):
    from advocc_ros.cli import main
    base = ['audit', '--scene', 'table_pick', '--out', str(tmp_path)]
    for extra, message in ((['--trials', '0'], '--trials'), (['--max-budget', '0'],
                                                             '--max-budget'),
                           (['--planners', 'rrtconnect,nope'], 'unknown planner'),
                           (['--time', '-1'], '--time'),
                           (['--target-psr', 'nan'], '--target-psr must be in 0..100'),
                           (['--target-psr', '101'], '--target-psr must be in 0..100'),
                           (['--target-psr', '0.2'], 'for 20 % give 20'),
                           (['--target-psr', 'few'], 'is not a number'),
                           (['--prefixes', '0,1.5'], 'non-negative integers'),
                           (['--prefixes', '-1'], 'non-negative integers'),
                           (['--prefixes', '0,9'], 'exceed --max-budget 5')):
        assert main(base + extra) == 2
        assert message in capsys.readouterr().err
    for extra in (['--method', 'nope'], ['--policy', 'nope']):
        with pytest.raises(SystemExit):
            main(base + extra)
    assert not list(tmp_path.iterdir())  # nothing ran


@pytest.fixture(autouse=True)
def _own_caches(tmp_path, monkeypatch):
    """Each audit here finds its own witness and goal sample: nothing another test left in this
    process's caches or in the session's disk cache (a scripted witness, a sample of a task with
    the same key) reaches it, and it leaves nothing behind."""
    from advocc_ros.model.cache import CACHE_ENV, clear_task_caches
    from advocc_ros.planning import witness_cache

    monkeypatch.setenv(CACHE_ENV, str(tmp_path / 'cache'))
    witness_cache.WITNESSES.clear()
    clear_task_caches()
    yield
    witness_cache.WITNESSES.clear()
    clear_task_caches()


@pytest.fixture(scope='module')
def small_heatmap(table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap
    return build_heatmap(table_scene, HeatmapConfig(samples=3000), seed=0, workers=1)


@pytest.mark.processes
def test_audit_end_to_end_table_pick(tmp_path, table_scene, small_heatmap):
    """Task / paper on table_pick: the first box blocks every goal pose (measured), so the PSR
    drops to the last evaluated prefix, the goal-valid fraction goes to 0, and the verdict of
    that prefix is 'goal blocked': the failure is no evidence against the planner."""
    from advocc_ros.audit.audit import run_audit
    from advocc_ros.audit.report import write_audit

    heatmap = small_heatmap
    cfg = AuditConfig(planners=('rrtconnect',), max_budget=2, trials=2, time_budget_s=2.0,
                      workers=1)
    seen = []
    audit = run_audit(table_scene, heatmap, cfg, progress=lambda m, p, row: seen.append((m, p)))
    paths = write_audit(audit, tmp_path, heatmap, table_scene)
    for name in ('audit.json', 'audit.md', 'audit_slices.png', 'audit_psr.png'):
        assert (tmp_path / name).stat().st_size > 0, name
    data = json.loads((tmp_path / 'audit.json').read_text())
    assert paths['audit.json'] == str(tmp_path / 'audit.json')
    assert data['method'] == 'task' and data['policy'] == 'paper'
    assert set(data['min_budget']) == {'0.8', '0.6', '0.4', '0.2', '0.0'}
    assert set(data['min_budget']['0.2']) == {'rrtconnect'}
    boxes = data['boxes']
    assert [b['id'] for b in boxes] == [f'adv_{i}' for i in range(len(boxes))]
    assert [b['pick'] for b in boxes] == list(range(1, len(boxes) + 1))
    assert 1 <= len(boxes) <= 2 and all(len(b['center_m']) == 3 for b in boxes)
    budgets = data['budgets']
    assert [b['m'] for b in budgets] == list(range(len(budgets)))
    assert 2 <= len(budgets) <= len(boxes) + 1
    assert seen == [(b['m'], 'rrtconnect') for b in budgets]
    for b in budgets:
        assert 0.0 <= b['goal_valid_fraction'] <= 1.0
        row = b['planners']['rrtconnect']
        assert set(row['failures']) == set(FAILURE_MODES)
        assert sum(row['failures'].values()) == row['trials'] - row['successes']
    assert budgets[0]['goal_valid_fraction'] == 1.0
    psr = data['psr']['rrtconnect']
    assert psr == [b['planners']['rrtconnect']['psr'] for b in budgets]
    assert psr[-1] < psr[0]
    assert budgets[1]['goal_valid_fraction'] == 0.0  # the first box blocks every goal pose
    md = (tmp_path / 'audit.md').read_text()
    assert md.index('## Answer') < md.index('## PSR per budget') < md.index('## Boxes')
    assert 'RRTConnect' in md and 'adv_0' in md
    assert budgets[0]['solvable'] == 'certified'
    assert data['witness']['source']['planner'] == 'rrtconnect'
    from advocc_ros.planning.witness import load_witness
    witness = load_witness(tmp_path / 'audit.witness.yaml')  # the 3D page animates it
    assert witness.waypoints.tolist() == data['witness']['waypoints']
    imp = data['impossible']
    assert imp['same_attack'] and imp['goal_blocked_m'] == 1
    assert budgets[1]['solvable'] == imp['prefixes'][0]['solvable'] == 'goal blocked'
    assert imp['prefixes'][0]['solvability']['goal_probe']['converged'] >= 500
    assert data['min_budget_solvable']['0.0']['rrtconnect'] is None  # m = 1 is not certified
    assert '| 1 | goal blocked |' in md


@pytest.mark.processes
def test_audit_policy_solvable_gives_both_answers(tmp_path, table_scene, small_heatmap):
    """--policy solvable: every evaluated prefix stays certified (the witness is kept by
    construction) and a second, paper-policy attack says how few boxes block the goal."""
    from advocc_ros.attack.task import TaskOptions
    from advocc_ros.audit.audit import run_audit
    from advocc_ros.audit.report import audit_answer, audit_markdown

    cfg = AuditConfig(planners=('rrtconnect',), max_budget=2, trials=2, time_budget_s=1.0,
                      policy='solvable', workers=1, task_options=TaskOptions(tube_samples=128))
    audit = run_audit(table_scene, small_heatmap, cfg)
    assert audit['policy'] == 'solvable'
    assert audit['settings']['task_options']['tube_samples'] == 128  # reaches the attack
    assert "task options (--task-option): {'approach_goals': 64" in audit_markdown(audit)
    assert [b['solvable'] for b in audit['budgets']] == ['certified'] * len(audit['budgets'])
    imp = audit['impossible']
    assert not imp['same_attack'] and imp['goal_blocked_m'] == 1 and len(imp['boxes']) >= 1
    assert audit['min_budget_solvable'] == audit['min_budget']  # every prefix certified
    _prefix_one_is_the_one_box_attack(audit, table_scene, small_heatmap, cfg)
    row = audit['budgets'][0]['planners']['rrtconnect']
    assert row['first_solution_median_s'] > 0 and set(row['psr_at']) == {'1'}
    text = audit_answer(audit)
    assert 'Impossible: 1 box of the Task attack under goal policy paper makes the pick ' \
        'impossible' in text
    assert '- RRTConnect ' in text and 'certified' in text


def _prefix_one_is_the_one_box_attack(audit, scene, heatmap, cfg):
    """Budgets nest: prefix 1 of the audit's attack is the one-box attack's box."""
    from advocc_ros.attack import attack
    from advocc_ros.attack.edges import task_witness
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot

    assert not [b for b in audit['budgets'] if 'boxes' in b]  # no prefix is an attack of its own
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    witness = task_witness(robot, scene.objects, q_init, scene.goal).witnesses
    one = attack(heatmap, robot, scene.objects, q_init, scene.goal, 1, 'task', seed=cfg.seed,
                 goal_policy='solvable', witness=witness, method_options=cfg.task_options)
    assert audit['boxes'][0]['center_m'] == [round(float(v), 4) for v in one.centers_m[0]]


def _hand_audit(psr, verdicts, goal_blocked_m):
    """A minimal audit dict for the report: one planner, its PSR curve and the verdicts."""
    from advocc_ros.audit.audit import minimal_budgets
    certified = [v if s == 'certified' else None for v, s in zip(psr, verdicts)]
    budgets = [{'m': m, 'solvable': s, 'goal_valid_fraction': 1.0, 'planners': {'rrtconnect': {
        'psr': v, 'first_solution_median_s': 0.1 * (m + 1),
        'failures': {'goal not sampled': 0, 'timed out': round(10 * (1 - v)),
                     'planning failed': 0, 'invalid path': 0}}}}
               for m, (v, s) in enumerate(zip(psr, verdicts))]
    prefixes = [{'m': m, 'solvable': s, 'solvability': {'message': 'why'}}
                for m, s in enumerate(verdicts) if m > 0][:goal_blocked_m or None]
    return {'scene': 'table_pick', 'method_label': 'Task', 'policy': 'solvable', 'max_budget': 3,
            'settings': {'box_size_m': 0.05, 'trials': 10, 'time_budget_s': 5.0},
            'psr': {'rrtconnect': psr}, 'budgets': budgets, 'boxes': [],
            'min_budget': minimal_budgets({'rrtconnect': psr}),
            'min_budget_solvable': minimal_budgets({'rrtconnect': certified}),
            'impossible': {'same_attack': False, 'goal_blocked_m': goal_blocked_m,
                           'prefixes': prefixes, 'boxes': []},
            'stopped': 'test'}


def test_audit_answer_names_both_numbers():
    from advocc_ros.audit.report import audit_answer, budget_table

    audit = _hand_audit([1.0, 0.6, 0.2, 0.0], ['certified'] * 4, goal_blocked_m=None)
    audit['impossible']['prefixes'] = [{'m': 1, 'solvable': 'certified'},
                                       {'m': 2, 'solvable': 'unknown'}]
    text = audit_answer(audit)
    assert 'Impossible: no prefix of the Task attack under goal policy paper blocks the goal ' \
        '(up to 2 boxes: m=1 certified, m=2 unknown)' in text
    assert '- RRTConnect fails (PSR <= 20 %) with 2 boxes, task certified: PSR 100 % -> 20 % ' \
        '(8 timed out); PSR 0 % with 3 boxes.' in text
    assert '| 2 | certified | 100 % | 20 % | 0.30 s | 8 timed out |' in budget_table(audit)


def test_audit_answer_does_not_count_a_blocked_goal_as_a_win():
    from advocc_ros.audit.report import audit_answer

    audit = _hand_audit([1.0, 0.7, 0.0], ['certified', 'certified', 'goal blocked'], 2)
    text = audit_answer(audit)
    assert 'Impossible: 2 boxes of the Task attack under goal policy paper make the pick ' \
        'impossible for every planner (goal blocked: why).' in text
    assert '- RRTConnect does not fail (PSR > 20 %) on a certified prefix (m = 0, 1): lowest ' \
        'PSR 70 % at m = 1 (unattacked 100 %), median time to first solution 0.10 s -> ' \
        '0.20 s (PT ratio x2.00); it fails with 2 boxes, where the task is goal blocked.' in text


@pytest.mark.processes
def test_audit_target_and_grid_stop_early(tmp_path, table_scene, small_heatmap):
    """Task / paper on table_pick (the first box blocks every goal pose): with the grid 0, 2
    and a 50 % target, m = 1 is never evaluated, m = 2 reaches the target and the sweep stops
    there; the skipped prefix is absent, gets no verdict and the report says so."""
    from advocc_ros.audit.audit import AUDIT_VERSION, run_audit
    from advocc_ros.audit.report import audit_answer, budget_table, write_audit

    cfg = AuditConfig(planners=('rrtconnect',), max_budget=2, trials=2, time_budget_s=1.0,
                      workers=1, target_psr=0.5, prefixes=(2,))
    audit = run_audit(table_scene, small_heatmap, cfg)
    assert len(audit['boxes']) == 2 and audit['version'] == AUDIT_VERSION == 4
    assert [b['m'] for b in audit['budgets']] == [0, 2]
    psr = audit['psr']['rrtconnect']
    assert len(psr) == 3 and psr[1] is None and psr[0] > 0.5 >= psr[2]
    assert audit['stopped'] == 'every planner at PSR <= 50 % (rrtconnect m = 2)'
    assert audit['min_budget']['0.5']['rrtconnect'] == 2
    assert audit['impossible']['goal_blocked_m'] == 1  # its own verdict for m = 1
    write_audit(audit, tmp_path, small_heatmap, table_scene)
    data = json.loads((tmp_path / 'audit.json').read_text())
    assert data['settings']['prefixes'] == [0, 2] and data['settings']['target_psr'] == 0.5
    assert audit_answer(data) == audit_answer(audit)
    assert 'it fails with 2 boxes (m = 1 not evaluated), where the task is goal blocked' \
        in audit_answer(data)
    assert 'Prefixes evaluated (--prefixes): m = 0, 2;' in audit_answer(data)
    assert 'm = 1: not evaluated (not in --prefixes).' in budget_table(data)
    from advocc_ros.view.scene_page import audit_view_html
    assert 'Prefixes evaluated (--prefixes): m = 0, 2;' in audit_view_html(tmp_path, table_scene)


@pytest.mark.processes
def test_audit_target_reached_unattacked_stops_at_once(table_scene, small_heatmap):
    """A 100 % target is reached by every planner on the unattacked task: nothing else runs."""
    from advocc_ros.audit.audit import run_audit

    cfg = AuditConfig(planners=('rrtconnect', 'bkpiece1'), max_budget=2, trials=1,
                      time_budget_s=0.5, workers=1, target_psr=1.0)
    audit = run_audit(table_scene, small_heatmap, cfg)
    assert [b['m'] for b in audit['budgets']] == [0]
    assert audit['stopped'] == 'every planner at PSR <= 100 % (rrtconnect m = 0, bkpiece1 m = 0)'
    assert '1.0' in audit['min_budget']


def _grid_audit():
    """A version-3 audit by hand: grid m = 0, 2, 5, target 20 %; RRTConnect reaches it at
    m = 2 (not evaluated at 5), PRM* at m = 5."""
    from advocc_ros.audit.audit import psr_curves

    def row(psr):
        return {'psr': psr, 'first_solution_median_s': 0.5, 'pt': 1.0,
                'failures': {'timed out': round(10 * (1 - psr))}}

    budgets = [{'m': m, 'solvable': 'certified', 'goal_valid_fraction': 1.0,
                'planners': {'rrtconnect': None if r is None else row(r), 'prmstar': row(p)}}
               for m, r, p in ((0, 1.0, 1.0), (2, 0.2, 0.6), (5, None, 0.0))]
    psr = psr_curves(budgets, ('rrtconnect', 'prmstar'))
    audit = _hand_audit([1.0], ['certified'], goal_blocked_m=None)
    audit.update(budgets=budgets, psr=psr, max_budget=5,
                 min_budget=minimal_budgets(psr), min_budget_solvable=minimal_budgets(psr))
    audit['settings'].update(target_psr=0.2, prefixes=[0, 2, 5])
    return audit


def test_audit_report_shows_skipped_cells():
    from advocc_ros.audit.report import audit_answer, budget_table

    audit = json.loads(json.dumps(_grid_audit()))  # what a reader of audit.json gets
    assert audit['psr']['rrtconnect'] == [1.0, None, 0.2, None, None, None]
    table = budget_table(audit)
    assert '| 5 | certified | 100 % | — | — | — | 0 % | 0.50 s | 10 timed out |' in table
    assert '—: not evaluated, the planner was already at PSR <= 20 % (--target-psr).' in table
    assert 'm = 1, 3, 4: not evaluated (not in --prefixes).' in table
    text = audit_answer(audit)
    assert '- RRTConnect fails (PSR <= 20 %) with 2 boxes (m = 1 not evaluated), task ' \
        'certified: PSR 100 % -> 20 % (8 timed out).' in text
    assert '- PRM* fails (PSR <= 20 %) with 5 boxes (m = 3..4 not evaluated)' in text
    assert 'Prefixes evaluated (--prefixes): m = 0, 2, 5;' in text


def test_audit_markdown_minimal_budgets_with_skipped_cells():
    from advocc_ros.audit.report import audit_markdown

    audit = _grid_audit()
    audit['impossible']['same_attack'] = True
    heatmap = {'valid_samples': 100, 'scene_name': 'table_pick'}
    audit['settings'].update(seed=0, workers=1, heatmap=heatmap)
    audit.update(method='task', witness=None, wall_s=1.0,
                 attack={'status': 'ok', 'message': '', 'compute_ms': 1.0},
                 machine={'cpu': 'cpu', 'cores': 2, 'python': '3.11'})
    md = audit_markdown(audit)
    assert '| RRTConnect | 2 | 2 | 2 | 2 | > 2 |' in md  # not evaluated after m = 2
    assert '| PRM* | 2 | 2 | 5 | 5 | 5 |' in md


def test_audit_figure_dots_the_lines_across_unevaluated_budgets():
    """With a grid of prefixes, the curve between evaluated m was not measured: dotted there."""
    import matplotlib.pyplot as plt

    from advocc_ros.evaluation.figures import audit_psr_figure

    fig = audit_psr_figure({'rrtconnect': [1.0, 0.9, None, 0.5, None, None, 0.2]}, [None] * 7)
    lines = fig.axes[0].get_lines()
    points = next(line for line in lines if line.get_label() == 'rrtconnect')
    styles = [(tuple(line.get_xdata()), line.get_linestyle()) for line in lines
              if line.get_color() == points.get_color() and line.get_linestyle() != 'None']
    plt.close(fig)
    assert styles == [((0, 1), '-'), ((1, 3), ':'), ((3, 6), ':')]
