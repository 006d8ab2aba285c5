"""Benchmark bookkeeping without ROS: plan, records (resume, dedupe, truncation), tables."""

import json

import pytest

from advocc_ros.bench import (BASELINE, BenchConfig, BenchError, RecordStore,
                              cell_rows, check_run_config, load_profile, plan_units, run_lock,
                              table1, table2, table4, trial_key)
from conftest import REPO


def _cfg(**changes):
    base = dict(scenes=('table_pick',), planners=('rrtconnect', 'bkpiece1'),
                methods=('ours', 'random'), budgets=(1, 3), trials=4, time_budget_s=1.0)
    base.update(changes)
    return BenchConfig(**base)


def _rec(scene, planner, method, budget, trial, success, pt=0.5, smr=0.05, cmr=0.02,
         jds=1.0, time_budget_s=1.0):
    return {'key': trial_key(scene, planner, method, budget, trial), 'scene': scene,
            'planner': planner, 'method': method, 'budget': budget, 'trial': trial,
            'seed': trial, 'success': success, 'status': 'SUCCESS' if success else 'TIMED_OUT',
            'planning_time_s': pt if success else time_budget_s, 'time_budget_s': time_budget_s,
            'min_manipulability': smr if success else None,
            'min_clearance_rad': cmr if success else None, 'jds_rad': jds if success else None}


# -- profiles and the run plan ----------------------------------------------------------------

def test_shipped_profiles_load():
    paper = load_profile(REPO / 'config' / 'bench.yaml', 'paper')
    assert paper.scenes == ('table_pick', 'table_under_pick', 'bookshelf')
    assert paper.planners == ('rrtconnect', 'prmstar', 'bkpiece1')
    assert paper.methods == ('task', 'ours', 'random', 'pfa', 'pfa++')
    assert paper.budgets == (1, 3, 5) and paper.trials == 500 and paper.time_budget_s == 5.0
    quick = load_profile(REPO / 'config' / 'bench.yaml', 'quick')
    assert quick.trials < 50
    with pytest.raises(BenchError, match='no profile'):
        load_profile(REPO / 'config' / 'bench.yaml', 'nope')


@pytest.mark.parametrize('changes, words', [
    (dict(budgets=(0,)), 'budgets'), (dict(budgets=(1, 'x')), 'budgets'),
    (dict(trials=0), 'trials'), (dict(trials=10**9), 'MAX_TRIALS'),
    (dict(sweep_trials=0), 'sweep_trials'), (dict(time_budget_s=float('nan')), 'time_budget_s'),
    (dict(scenes=()), 'scenes'), (dict(planners=('a', 'a')), 'duplicates'),
    (dict(shims=0), 'external_shims'), (dict(variants={'random': 0}), 'variants'),
    (dict(skip=('pfa++',)), 'skip'), (dict(box_size_m=-1.0), 'box_size_m'),
    (dict(victim_margin_m=0.06), 'victim_margin_m'),
    (dict(victim_margin_m='4 mm'), 'victim_margin_m'),
])
def test_bad_settings_are_rejected(changes, words):
    with pytest.raises(BenchError, match=words):
        _cfg(**changes)


def test_unknown_setting_is_named():
    with pytest.raises(BenchError, match='trails'):
        BenchConfig.from_data({'trails': 3})


def test_plan_units_covers_every_trial_once():
    cfg = _cfg(methods=('ours', 'random', 'pfa++'), variants={'random': 3},
               skip=('pfa++:rrtconnect',), sweep_budgets=(5,), sweep_trials=2)
    units, notes = plan_units(cfg)
    keys = [t.key for u in units for t in u.trials]
    assert len(keys) == len(set(keys))
    # baseline 2x4; ours 2 planners x (4+4+2); random same; pfa++ only bkpiece1: 4+4+2
    assert len(keys) == 8 + 20 + 20 + 10
    assert units[0].attack is None and {t.method for t in units[0].trials} == {BASELINE}
    random_units = [u for u in units if u.attack and u.attack.method == 'random']
    # 3 variants at budgets 1 and 3; only 2 at the sweep budget (2 trials); both planners each
    assert len(random_units) == 3 + 3 + 2
    assert {u.attack.seed for u in random_units} == {0, 1, 2}
    b1 = [u for u in random_units if u.attack.budget == 1]
    assert sorted(t.trial for u in b1 for t in u.trials if t.planner == 'bkpiece1') == \
        [0, 1, 2, 3]
    pfa = [u for u in units if u.attack and u.attack.method == 'pfa++']
    assert {u.attack.planner for u in pfa} == {'bkpiece1'}
    assert all(u.attack.tag.startswith('pfapp_b') for u in pfa)
    assert any('pfa++ on rrtconnect' in n for n in notes)
    # Trial k plans with seed + k in every cell: methods are compared on the same seeds.
    assert {t.seed - t.trial for u in units for t in u.trials} == {cfg.seed}


def test_unavailable_methods_are_skipped_with_a_note():
    units, notes = plan_units(_cfg(methods=('ours', 'pfa')), available=['ours'])
    assert {u.attack.method for u in units if u.attack} == {'ours'}
    assert any("'pfa' skipped" in n for n in notes)


# -- records ----------------------------------------------------------------------------------

def test_records_append_dedupe_and_resume(tmp_path):
    path = tmp_path / 'records.jsonl'
    store = RecordStore(path)
    assert store.append(_rec('s', 'p', 'ours', 1, 0, True))
    assert not store.append(_rec('s', 'p', 'ours', 1, 0, False))  # same key: refused
    assert store.append(_rec('s', 'p', 'ours', 1, 1, False))
    assert len(path.read_text().splitlines()) == 2
    again = RecordStore(path)
    assert len(again) == 2 and trial_key('s', 'p', 'ours', 1, 0) in again
    assert again.records[trial_key('s', 'p', 'ours', 1, 0)]['success'] is True


def test_truncated_last_line_is_dropped_and_appending_continues(tmp_path):
    path = tmp_path / 'records.jsonl'
    lines = [json.dumps(_rec('s', 'p', 'ours', 1, k, True)) for k in range(3)]
    # A kill mid-write: the last record is cut; a foreign duplicate line is also present.
    path.write_text('\n'.join(lines[:2] + [lines[0]]) + '\n' + lines[2][:40])
    store = RecordStore(path)
    assert len(store) == 2 and store.duplicates == 1
    assert path.read_text().endswith('\n')
    assert store.append(_rec('s', 'p', 'ours', 1, 2, False))
    reread = RecordStore(path)
    assert len(reread) == 3 and reread.bad_lines == 0
    assert reread.records[trial_key('s', 'p', 'ours', 1, 2)]['success'] is False


def test_whole_last_line_without_newline_is_kept(tmp_path):
    path = tmp_path / 'records.jsonl'
    path.write_text(json.dumps(_rec('s', 'p', 'ours', 1, 0, True)))
    store = RecordStore(path)
    assert len(store) == 1
    store.append(_rec('s', 'p', 'ours', 1, 1, True))
    assert len(RecordStore(path)) == 2


def test_garbage_lines_are_skipped(tmp_path):
    path = tmp_path / 'records.jsonl'
    path.write_text('not json\n{"no_key": 1}\n' + json.dumps(_rec('s', 'p', 'ours', 1, 0, True))
                    + '\n')
    store = RecordStore(path)
    assert len(store) == 1 and store.bad_lines == 2


def test_run_folder_lock_and_settings_check(tmp_path):
    with run_lock(tmp_path):
        with pytest.raises(BenchError, match='in use'):
            with run_lock(tmp_path):
                pass
    with run_lock(tmp_path):  # released
        pass
    cfg = _cfg()
    (tmp_path / 'config.json').write_text(json.dumps({'config': cfg.to_data()}))
    check_run_config(tmp_path, _cfg(trials=10))  # more trials: fine, the run is extended
    with pytest.raises(BenchError, match='time_budget_s'):
        check_run_config(tmp_path, _cfg(time_budget_s=5.0))
    with pytest.raises(BenchError, match='victim_margin_m'):  # other attacks: another run
        check_run_config(tmp_path, _cfg(victim_margin_m=0.004))


def test_the_benchs_heatmap_server_gets_the_victim_margin_and_the_task_options(tmp_path):
    from advocc_ros.orchestrator.sources import server_parameters

    heatmap = tmp_path / 'h.npz'
    plain = server_parameters(_cfg(), tmp_path, heatmap)
    assert plain['victim_margin_m'] == 0.0 and plain['search_witness'] is True
    given = server_parameters(_cfg(victim_margin_m=0.004, task={'detours': 1}), tmp_path,
                              heatmap)
    assert given['victim_margin_m'] == 0.004 and given['task_detours'] == 1
    assert given['heatmap_file'] == str(heatmap) and str(tmp_path) in given['allowed_dirs']


# -- aggregation and tables ------------------------------------------------------------------

def _records():
    recs = []
    for k in range(4):
        recs.append(_rec('table_pick', 'rrtconnect', BASELINE, 0, k, True, smr=0.08))
        recs.append(_rec('table_pick', 'rrtconnect', 'ours', 1, k, k < 2, smr=0.04, cmr=0.01,
                         jds=2.0, pt=0.8))
        recs.append(_rec('table_pick', 'rrtconnect', 'random', 1, k, k < 3, smr=0.06,
                         cmr=0.03, jds=1.5))
        recs.append(_rec('table_pick', 'rrtconnect', 'ours', 3, k, False))
        recs.append(_rec('table_pick', 'rrtconnect', 'random', 3, k, k < 3))
    recs.append(_rec('table_pick', 'bkpiece1', 'ours', 1, 0, True))  # 1 of 4: incomplete
    return recs


def test_cell_rows_follow_the_paper_definitions():
    rows = cell_rows(_records(), _cfg())
    ours1 = rows[('table_pick', 'rrtconnect', 'ours', 1)]
    assert ours1['psr'] == 0.5 and ours1['complete']
    assert ours1['smr'] == pytest.approx(4.0) and ours1['cmr'] == pytest.approx(1.0)  # x10^-2
    assert ours1['pt'] == pytest.approx((0.8 + 0.8 + 1.0 + 1.0) / 4)  # failure = budget
    ours3 = rows[('table_pick', 'rrtconnect', 'ours', 3)]
    assert ours3['psr'] == 0 and ours3['smr'] is None and ours3['jds'] is None
    assert not rows[('table_pick', 'bkpiece1', 'ours', 1)]['complete']


def test_table1_layout():
    md, csv_text = table1(cell_rows(_records(), _cfg()), _cfg())
    lines = md.splitlines()
    assert lines[0] == ('| Scene | Planner | Method | PSR@1 | SMR@1 | CMR@1 | JDS@1 | PT@1 | '
                        'PSR@3 | SMR@3 | CMR@3 | JDS@3 | PT@3 |')
    ours = next(line for line in lines if '| RRT | Ours |' in line)[:-2].split(' | ')
    assert ours[3:8] == ['**50.00**', '**4.000**', '**1.000**', '**2.000**', '**0.900**']
    assert ours[8:13] == ['**0.00**', 'N/A', 'N/A', 'N/A', '**1.000**']
    random = next(line for line in lines if '| RRT | Random |' in line).split(' | ')
    assert random[3:8] == ['75.00', '6.000', '3.000', '1.500', '0.625']
    bk = next(line for line in lines if '| BKPIECE | Ours |' in line)[:-2].split(' | ')
    assert bk[3] == '100.00*' and bk[8] == '--'  # incomplete cell; budget 3 not run
    assert 'Scene 1 (table_pick)' in lines[2]
    header, *rows = csv_text.splitlines()
    assert header.startswith('scene_index,scene,planner,method,budget,trials')
    assert any(r.startswith('1,table_pick,rrtconnect,ours,3,4,4,0,0,0,N/A,N/A,N/A,1,')
               for r in rows)


def _cell(psr, trials=10):
    return {'psr': psr, 'trials': trials, 'successes': round(psr * trials), 'complete': True,
            'internal_errors': 0}


def test_table2_minimal_budgets_and_variations():
    cfg = BenchConfig(scenes=('table_pick',), planners=('rrtconnect',), methods=('task',),
                      budgets=(1, 3), sweep_budgets=(2,), trials=10, variations=1)
    var = '/run/scenes/table_pick_0000.yaml'
    rows = {('table_pick', 'rrtconnect', BASELINE, 0): _cell(1.0),
            ('table_pick', 'rrtconnect', 'task', 1): _cell(0.9),
            ('table_pick', 'rrtconnect', 'task', 2): _cell(0.5),
            ('table_pick', 'rrtconnect', 'task', 3): _cell(0.0),
            (var, 'rrtconnect', BASELINE, 0): _cell(1.0),
            (var, 'rrtconnect', 'task', 1): _cell(0.2),
            (var, 'rrtconnect', 'task', 2): _cell(0.1),
            (var, 'rrtconnect', 'task', 3): _cell(0.1)}
    md, text = table2(rows, cfg, {'table_pick': [var]})
    cells = md.strip().split('\n')[-1].split(' | ')
    # 80 %: 2 and 1 -> 1.5; 60 %: 2, 1 -> 1.5; 40 %: 3, 1 -> 2; 20 %: 3, 1 -> 2; 0 %: 3 only
    assert cells[-5:] == ['1.5', '1.5', '2', '2', '3 (1/2) |']
    assert text.split('\n')[1] == 'table_pick,rrtconnect,task,"0,1,2,3",2,3,1.5,1.5,2,2,3'
    assert md.split('\n')[0].endswith('| 80% | 60% | 40% | 20% | 0% |')
    assert text.split('\n')[0].endswith('psr_le_80,psr_le_60,psr_le_40,psr_le_20,psr_le_0')
    alone, _ = table2(rows, cfg)
    assert alone.strip().split('\n')[-1].split(' | ')[-5:] == ['2', '2', '3', '3', '3 |']


def test_table2_reports_greater_than_max_when_not_reached():
    md, csv_text = table2(cell_rows(_records(), _cfg()), _cfg())
    ours = next(line for line in md.splitlines() if '| RRT | Ours |' in line)
    assert ours.endswith('| 0,1,3 | 1 | 1 | 1 | 3 | 3 | 3 |')  # budgets, tasks, thresholds
    random = next(line for line in md.splitlines() if '| RRT | Random |' in line)
    assert random.endswith('| 0,1,3 | 1 | 1 | > 3 | > 3 | > 3 | > 3 |')
    assert 'table_pick,rrtconnect,random,"0,1,3",1,3,1,>3,>3,>3,>3' in csv_text


def test_table4_offline_online():
    attacks = [{'method': 'ours', 'compute_s': 1.0}, {'method': 'ours', 'compute_s': 3.0},
               {'method': 'random', 'compute_s': 0.1},
               {'method': 'pfa++', 'planner': 'prmstar', 'planner_specific': True,
                'compute_s': 100.0}]
    md, csv_text = table4(attacks, {'a': {'build_s': 1000.0}, 'b': {'build_s': 1200.0}})
    lines = md.splitlines()
    assert [line.split(' | ')[0] for line in lines[2:]] == ['| Random', '| PFA++ (PRM*)',
                                                            '| Ours']
    assert lines[-1] == '| Ours | 1100.00 | 2.000 | 1102.00 | 2 |'
    assert 'pfa++,prmstar,N/A,100,100,1' in csv_text


def test_plan_runs_variations_at_every_budget_after_their_scene():
    cfg = _cfg(methods=('task',), budgets=(1, 3), sweep_budgets=(2,), trials=4, sweep_trials=2,
               variations=1, baseline=False)
    var = '/run/scenes/table_pick_0000.yaml'
    units, _ = plan_units(cfg, variations={'table_pick': [var]})
    assert [u.scene for u in units][-1] == var and units[0].scene == 'table_pick'
    var_units = [u for u in units if u.scene == var]
    assert {t.budget for u in var_units for t in u.trials} == {0, 1, 2, 3}  # with m = 0
    assert all(len([t for t in u.trials if t.planner == 'rrtconnect']) == 2 for u in var_units)
    assert not any(u.attack is None for u in units if u.scene == 'table_pick')


def test_hardness_table_and_time_figure(tmp_path):
    """PSR@t from first-solution times, the PT ratio against the baseline, solvable verdicts
    from the attack files, and the success-vs-time figure in the report."""
    from advocc_ros.bench import write_report
    from advocc_ros.bench.tables import hardness_table

    cfg = _cfg(methods=('task',), budgets=(1,), planners=('prmstar',), time_budget_s=5.0)
    recs = []
    for k, first in enumerate((0.2, 0.2, 0.4, 0.4)):
        recs.append(dict(_rec('table_pick', 'prmstar', BASELINE, 0, k, True, pt=4.9,
                              time_budget_s=5.0), first_solution_s=first))
    for k, first in enumerate((0.5, 1.5, 3.0, None)):
        recs.append(dict(_rec('table_pick', 'prmstar', 'task', 1, k, first is not None, pt=4.9,
                              time_budget_s=5.0), first_solution_s=first))
    rows = cell_rows(recs, cfg)
    attacks = [{'path': tmp_path / 'attacks' / 'table_pick' / f'task_{i}.yaml', 'method': 'task',
                'budget': 1, 'solvable': verdict}
               for i, verdict in enumerate(({'verdict': 'certified'}, 'certified', 'unknown'))]
    md, csv_text = hardness_table(rows, attacks, cfg, {'table_pick': 'table_pick'})
    lines = md.splitlines()
    assert lines[0] == ('| Scene | Planner | Method | M | Trials | PSR | PSR@1s | PSR@2s | '
                        'PSR@5s | T1st median [s] | T1st p90 [s] | PT ratio | Solvable c/b/u |')
    base = next(line for line in lines if '| None |' in line).split(' | ')
    assert base[6:12] == ['100', '100', '100', '0.300', '0.400', 'x1.00']
    task = next(line for line in lines if '| Task |' in line)[:-2].split(' | ')
    # medians: attacked (1.5 + 3.0) / 2 = 2.25 s vs unattacked 0.3 s
    assert task[5:13] == ['75.00', '25', '50', '75', '2.250', '4.400', 'x7.50', '2/0/1']
    header, base_csv, task_csv = csv_text.splitlines()
    assert header.split(',')[6:9] == ['psr_at_1s_percent', 'psr_at_2s_percent',
                                      'psr_at_5s_percent']
    assert task_csv.endswith(',1,7.5,2,0,1')

    store = RecordStore(tmp_path / 'records.jsonl')
    for rec in recs:
        store.append(rec)
    out = write_report(tmp_path, cfg)
    assert 'PSR@1s' in out['hardness.md'].read_text()
    assert out['figures/time_to_solution_table_pick.png'].stat().st_size > 10_000
