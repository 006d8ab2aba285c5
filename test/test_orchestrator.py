"""The orchestrator through real processes: a tiny benchmark, resume after SIGKILL, node faults.

Protocol of every test: table_pick, RRTConnect + BKPIECE1, Ours + Random, budget 1, 1 s plans,
two local shims, a 1000-sample heatmap built once for the module.
"""

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

from advocc_ros.bench import RecordStore

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

PLANNERS = ('rrtconnect', 'bkpiece1')


@pytest.fixture(scope='module')
def heatmap_file(tmp_path_factory):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import load_scene

    path = tmp_path_factory.mktemp('heatmap') / 'table_pick.npz'
    save_heatmap(build_heatmap(load_scene(scene_path('table_pick')),
                               HeatmapConfig(samples=1000), workers=1), path)
    return path


def _start(out, heatmap_file, env, trials=3):
    args = [sys.executable, '-m', 'advocc_ros.orchestrator', '--profile', 'quick',
            '--out', str(out), '--scenes', 'table_pick', '--planners', ','.join(PLANNERS),
            '--methods', 'ours,random', '--budgets', '1', '--trials', str(trials),
            '--time-budget', '1', '--variants', 'random=1', '--shims', '2',
            '--heatmap', f'table_pick={heatmap_file}', '--set', 'start_timeout_s=90',
            '--set', 'plan_timeout_margin_s=15', '--set', 'task={detours: 1}']
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def _planned(trials):
    return len(PLANNERS) * trials * 3  # baseline + ours + random


def _finish(proc, timeout=180):
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f'orchestrator did not finish within {timeout} s:\n{out}')
    return proc.returncode, out


def _lines(out):
    path = out / 'records.jsonl'
    return path.read_text().splitlines() if path.exists() else []


def _wait_records(proc, out, n, timeout=120):
    deadline = time.monotonic() + timeout
    while len(_lines(out)) < n:
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, f'fewer than {n} records after {timeout} s'
        time.sleep(0.1)


def _children(out):
    return json.loads((out / 'children.json').read_text())


def _gone(pid, timeout=20):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        # A zombie of ours does not count as running.
        try:
            if pathlib.Path(f'/proc/{pid}/stat').read_text().split()[2] == 'Z':
                return True
        except (OSError, IndexError):
            return True
        time.sleep(0.2)
    return False


def _check_complete(out, trials):
    lines = _lines(out)
    keys = [json.loads(line)['key'] for line in lines]
    assert len(keys) == len(set(keys)), 'duplicated trials'
    assert len(keys) == _planned(trials), f'{len(keys)} records, {_planned(trials)} planned'
    assert len(RecordStore(out / 'records.jsonl')) == _planned(trials)
    return [json.loads(line) for line in lines]


def test_tiny_benchmark_killed_resumes_to_its_end(tmp_path, heatmap_file, ros_env):
    """The tiny benchmark, kill -9 of the orchestrator after 5 records (its nodes die with
    it), the same command again: the first run's records kept, the rest planned, every output
    written; once more: nothing planned, no node started."""
    out = tmp_path / 'run'
    trials = 3
    proc = _start(out, heatmap_file, ros_env, trials)
    _wait_records(proc, out, 5)
    children = _children(out)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    interrupted = len(_lines(out))
    assert 5 <= interrupted < _planned(trials)
    for name, child in children.items():  # PR_SET_PDEATHSIG: nodes die with the orchestrator
        assert _gone(child['pid']), f'{name} outlived the orchestrator'
    code, text = _finish(_start(out, heatmap_file, ros_env, trials))
    assert code == 0, text
    records = _check_complete(out, trials)
    # The resumed run kept the first run's records (same lines first) and reused the attacks.
    assert _lines(out)[:interrupted - 1] == [json.dumps(r, sort_keys=True)
                                             for r in records[:interrupted - 1]]
    log = (out / 'logs' / 'advocc_shim_table_pick_0.log').read_text()
    assert log.count('=== start #1') == 2  # one start per orchestrator session
    # the last line the kill left may be torn (it is planned again)
    _check_outputs(out, records, planned_now=(_planned(trials) - interrupted,
                                              _planned(trials) - interrupted + 1))
    for name, child in _children(out).items():
        assert _gone(child['pid']), f'{name} still running'
    # Re-running the finished command plans nothing and starts no node.
    code, text = _finish(_start(out, heatmap_file, ros_env), timeout=60)
    assert code == 0, text
    _check_complete(out, trials)


def _check_outputs(out, records, planned_now):
    """A finished tiny benchmark's records, tables, figures and summary; ``planned_now``: the
    trial counts its last session may have planned."""
    assert {(r['method'], r['budget']) for r in records} \
        == {('none', 0), ('ours', 1), ('random', 1)}
    assert {r['shim'] for r in records} \
        == {'/advocc_shim_table_pick_0', '/advocc_shim_table_pick_1'}
    for r in records:
        assert r['time_budget_s'] == 1.0
        if r['success']:
            assert r['min_manipulability'] > 0 and r['jds_rad'] > 0
            assert r['min_clearance_rad'] >= 0 and r['waypoints'] >= 2
            assert 0 < r['first_solution_s'] <= r['planning_time_s']
        else:
            assert r['min_manipulability'] is None and r['first_solution_s'] is None
    # Baseline: the unattacked table is solvable.
    base = [r for r in records if r['method'] == 'none' and r['planner'] == 'rrtconnect']
    assert sum(r['success'] for r in base) >= 2
    # Attacks are cached with unique ids; the trials ran against them.
    for tag in ('ours_b1_v0', 'random_b1_v0'):
        text_yaml = (out / 'attacks' / 'table_pick' / f'{tag}.yaml').read_text()
        assert f'id: {tag}_0' in text_yaml
    assert '| PSR@1s |' in (out / 'hardness.md').read_text()
    assert (out / 'figures' / 'time_to_solution_table_pick.png').stat().st_size > 0
    table = (out / 'table1.md').read_text()
    assert '| Scene | Planner | Method | PSR@1 | SMR@1 | CMR@1 | JDS@1 | PT@1 |' in table
    for row in ('| Scene 1 (table_pick) | RRT | Ours |', '| Scene 1 (table_pick) | RRT | Random |',
                '| Scene 1 (table_pick) | BKPIECE | Ours |'):
        assert row in table
    assert '| Scene 1 (table_pick) | RRT | 3 |' in table  # baseline table
    assert 'table_pick,rrtconnect,ours,1,3,3' in (out / 'table1.csv').read_text()
    assert '| Ours |' in (out / 'table4.md').read_text()
    assert '80%' in (out / 'table2.md').read_text()
    for fig in ('psr_vs_budget_table_pick.png', 'heatmap_table_pick.png'):
        assert (out / 'figures' / fig).stat().st_size > 1000
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['status'] == 'complete' and summary['missing'] == 0
    assert summary['restarts'] == {}
    # The server may read the run folder's heatmap wherever --out is (not only under cwd/tmp).
    server_log = (out / 'logs' / 'advocc_heatmap_table_pick.log').read_text()
    assert f'"{out.resolve()}"' in server_log.split('allowed_dirs:=', 1)[1].splitlines()[0]
    assert 'task_detours:=1' in server_log.split('allowed_dirs:=', 1)[1].splitlines()[0]
    assert json.loads((out / 'config.json').read_text())['config']['task'] == {'detours': 1}
    # Throughput: the trials this session planned over the time its trial loops took.
    assert summary['trials_run'] in planned_now and summary['done'] == len(records)
    assert 0 < summary['trial_phase_s'] < summary['wall_s']
    assert summary['trials_per_s'] == pytest.approx(
        summary['trials_run'] / summary['trial_phase_s'], rel=0.01)


def test_node_faults_are_survived(tmp_path, heatmap_file, ros_env):
    """kill -9 of a shim and of the heatmap server mid-run: restarted, nothing lost or doubled."""
    out = tmp_path / 'run'
    trials = 4
    proc = _start(out, heatmap_file, ros_env, trials)
    _wait_records(proc, out, 2)
    children = _children(out)
    os.kill(children['advocc_shim_table_pick_0']['pid'], signal.SIGKILL)
    os.kill(children['advocc_heatmap_table_pick']['pid'], signal.SIGKILL)
    code, text = _finish(proc)
    assert code == 0, text
    _check_complete(out, trials)
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['restarts'].get('advocc_shim_table_pick_0') == 1, summary
    assert summary['restarts'].get('advocc_heatmap_table_pick') == 1, summary
    after = _children(out)
    assert after['advocc_shim_table_pick_0']['starts'] == 2
    assert after['advocc_shim_table_pick_0']['pid'] != children['advocc_shim_table_pick_0']['pid']
    assert 'restarting' in text
    # The attacks were generated by the restarted server (it was killed before them).
    assert (out / 'attacks' / 'table_pick' / 'ours_b1_v0.yaml').exists()


def test_sigint_stops_every_child(tmp_path, heatmap_file, ros_env):
    out = tmp_path / 'run'
    proc = _start(out, heatmap_file, ros_env)
    _wait_records(proc, out, 1)
    children = _children(out)
    proc.send_signal(signal.SIGINT)
    code, text = _finish(proc, timeout=60)
    assert code == 130, text
    assert 'interrupted' in text and 'Traceback' not in text
    for name, child in children.items():
        assert _gone(child['pid'], timeout=2), f'{name} still running after the orchestrator'
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['status'] == 'interrupted' and summary['done'] >= 1


def test_planner_in_the_loop_attack_queries_the_shims(tmp_path, heatmap_file, ros_env):
    """PFA's optimiser plans through the shims' ~/plan (each query's boxes injected first)."""
    out = tmp_path / 'run'
    args = [sys.executable, '-m', 'advocc_ros.orchestrator', '--profile', 'quick',
            '--out', str(out), '--scenes', 'table_pick', '--planners', 'rrtconnect',
            '--methods', 'pfa', '--budgets', '1', '--trials', '2', '--time-budget', '1',
            '--no-baseline', '--shims', '2', '--heatmap', f'table_pick={heatmap_file}',
            '--set', 'pfa={queries: 9, queries_per_placement: 3, query_time_s: 0.5}']
    code, text = _finish(subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE,
                                          stderr=subprocess.STDOUT, text=True))
    assert code == 0, text
    import yaml
    meta = yaml.safe_load((out / 'attacks' / 'table_pick' / 'pfa_b1_v0.yaml').read_text())
    assert meta['method'] == 'pfa' and len(meta['objects']) == 1
    assert meta['pfa']['queries'] == 9 and meta['pfa']['planner'] == 'rrtconnect'
    assert sum(meta['pfa']['statuses'].values()) == 9
    served = 0
    for i in range(2):  # 9 queries + 2 trials were planned by the shims
        served += (out / 'logs' / f'advocc_shim_table_pick_{i}.log').read_text().count('plan #')
    assert served == 9 + 2
    assert len(_lines(out)) == 2


def test_external_shim_is_discovered_and_used(tmp_path, heatmap_file, ros_env):
    """A shim the orchestrator did not start (another host, same domain) serves trials. The
    orchestrator starts once the shim says it is up: on a loaded machine it may take longer
    than the orchestrator's first look for external shims."""
    out, remote_log = tmp_path / 'run', tmp_path / 'remote_shim.log'
    with remote_log.open('w') as log_file:
        remote = subprocess.Popen(
            [sys.executable, '-m', 'advocc_ros.nodes.planner_shim', '--ros-args', '-r',
             '__node:=remote_shim', '-p', 'scene_file:=table_pick'],
            env=ros_env, stdout=log_file, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while 'planning worker pid' not in remote_log.read_text():
            assert remote.poll() is None, remote_log.read_text()
            assert time.monotonic() < deadline, 'the remote shim did not start in 120 s'
            time.sleep(0.1)
        args = [sys.executable, '-m', 'advocc_ros.orchestrator', '--profile', 'quick',
                '--out', str(out), '--scenes', 'table_pick', '--planners', 'rrtconnect',
                '--methods', 'ours', '--budgets', '1', '--trials', '6', '--time-budget', '1',
                '--shims', '1', '--external-shims', '--heatmap', f'table_pick={heatmap_file}']
        code, text = _finish(subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE,
                                              stderr=subprocess.STDOUT, text=True))
        assert code == 0, text
        assert remote.poll() is None, 'the orchestrator must not stop a shim it did not start'
    finally:
        remote.send_signal(signal.SIGINT)
        try:
            remote.wait(timeout=20)
        except subprocess.TimeoutExpired:
            remote.kill()
            remote.wait()
    records = [json.loads(line) for line in _lines(out)]
    assert len(records) == 12
    shims = {r['shim'] for r in records}
    assert shims == {'/advocc_shim_table_pick_0', '/remote_shim'}, shims


def test_the_bench_server_may_read_the_heatmap_file_the_user_gave(tmp_path):
    """``advocc bench --heatmap /data/hm.npz``: the heatmap server it starts may read that file
    (not only the run folder, the working directory and the temporary directory), and no more
    of the disk than its folder."""
    from advocc_ros.orchestrator.sources import server_allowed_dirs
    from advocc_ros.paths import PathError, allowed_dirs, confine
    given = pathlib.Path('/advocc-test-data/heatmaps/table_pick.npz')
    dirs = allowed_dirs(server_allowed_dirs(tmp_path / 'run', given))
    assert confine(given, dirs, 'heatmap_file') == given
    assert confine(tmp_path / 'run' / 'heatmaps' / 'box.npz', dirs, 'heatmap_file')
    with pytest.raises(PathError, match='outside the allowed directories'):
        confine('/advocc-test-data/other/table_pick.npz', dirs, 'heatmap_file')
