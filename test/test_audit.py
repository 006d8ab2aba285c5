"""The audit: minimal budgets from PSR curves, and one small audit end to end on table_pick."""

import json

import pytest

from advocc_ros.evaluation.audit import AuditConfig, minimal_budgets


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


def test_audit_command_errors(tmp_path, capsys):
    from advocc_ros.cli import main
    base = ['audit', '--scene', 'table_pick', '--out', str(tmp_path)]
    for extra, message in ((['--trials', '0'], '--trials'), (['--max-budget', '0'],
                                                             '--max-budget'),
                           (['--planners', 'rrtconnect,nope'], 'unknown planner'),
                           (['--time', '-1'], '--time')):
        assert main(base + extra) == 2
        assert message in capsys.readouterr().err
    for extra in (['--method', 'nope'], ['--policy', 'nope']):
        with pytest.raises(SystemExit):
            main(base + extra)
    assert not list(tmp_path.iterdir())  # nothing ran


def test_audit_end_to_end_table_pick(tmp_path, table_scene):
    """Task / paper on table_pick: the first box blocks every goal pose (measured), so the PSR
    drops to the last evaluated prefix and the goal-valid fraction goes to 0."""
    from advocc_ros.evaluation.audit import run_audit
    from advocc_ros.evaluation.audit_report import write_audit
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap

    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=3000), seed=0, workers=1)
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
        assert set(row['failures']) == {'goal blocked', 'timed out', 'planning failed'}
        assert sum(row['failures'].values()) == row['trials'] - row['successes']
    assert budgets[0]['goal_valid_fraction'] == 1.0
    psr = data['psr']['rrtconnect']
    assert psr == [b['planners']['rrtconnect']['psr'] for b in budgets]
    assert psr[-1] < psr[0]
    assert budgets[1]['goal_valid_fraction'] < 1.0
    md = (tmp_path / 'audit.md').read_text()
    assert md.index('## Answer') < md.index('## PSR per budget') < md.index('## Boxes')
    assert 'RRTConnect' in md and 'adv_0' in md
