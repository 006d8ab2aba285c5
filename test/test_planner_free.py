"""The attack core queries no planner: ``attack()`` starts no process and imports no
planner; the task's witness is data found at the edges (``attack.edges``), timed apart."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO

SPAWN_EVENTS = ('subprocess.Popen', 'os.fork', 'os.forkpty', 'os.posix_spawn', 'os.spawn',
                'os.exec', 'os.system')
"""Python audit events of every way a Python process starts another one."""


@pytest.fixture(scope='module')
def table(heatmap_file, table_scene, panda):
    from advocc_ros.heatmap import load_heatmap
    from advocc_ros.kinematics.ik import start_configuration

    return (load_heatmap(heatmap_file), panda, table_scene,
            start_configuration(table_scene, panda))


@pytest.fixture
def no_process(monkeypatch):
    """Every way this process could start another one raises (and is recorded)."""
    import multiprocessing
    import subprocess as sp

    started = []

    def refuse(what):
        def start(*args, **kwargs):
            started.append(what)
            raise RuntimeError(f'{what}: the attack core started a process')
        return start

    monkeypatch.setattr(sp.Popen, '__init__', refuse('subprocess.Popen'))
    monkeypatch.setattr(multiprocessing.Process, 'start', refuse('multiprocessing'))
    for name in ('fork', 'forkpty', 'posix_spawn', 'posix_spawnp', 'system'):
        if hasattr(os, name):
            monkeypatch.setattr(os, name, refuse(f'os.{name}'))
    return started


@pytest.mark.parametrize('method,policy', [('task', 'paper'), ('ours', 'reachable'),
                                           ('random', 'paper')])
def test_attack_under_paper_and_reachable_starts_no_process(table, no_process, method,
                                                            policy):
    from advocc_ros.attack import attack

    heatmap, robot, scene, q = table
    result = attack(heatmap, robot, scene.objects, q, scene.goal, 2, method, seed=1,
                    goal_policy=policy)
    assert result.status.ok, result.message
    assert no_process == []
    # No witness was handed in: the verdict says so and is never "certified".
    assert result.witness is None and 'witness_search_ms' not in result.stats
    assert result.solvable.verdict in ('goal blocked', 'unknown'), result.solvable.message
    assert 'no witness' in result.solvable.message


@pytest.fixture(scope='module')
def witness(table):
    """The task's witness, found as the edges find it (a planning worker), before any test
    forbids processes."""
    from advocc_ros.planning.witness_cache import find_witnesses

    heatmap, robot, scene, q = table
    found = find_witnesses(robot, scene.objects, q, scene.goal)
    assert found
    return found[0]


@pytest.mark.processes  # the witness fixture's search (a planning worker)
def test_solvable_takes_the_witness_as_data(table, witness, no_process):
    from advocc_ros.attack import AttackStatus, attack

    heatmap, robot, scene, q = table
    refused = attack(heatmap, robot, scene.objects, q, scene.goal, 2, 'random', seed=1,
                     goal_policy='solvable')
    assert refused.status == AttackStatus.NO_WITNESS and 'witness' in refused.message
    assert not refused.obstacles
    result = attack(heatmap, robot, scene.objects, q, scene.goal, 2, 'random', seed=1,
                    goal_policy='solvable', witness=witness)
    assert result.status.ok and result.witness is witness and no_process == []
    assert result.solvable.certified, result.solvable.message


@pytest.mark.processes  # the witness fixture's search (a planning worker)
def test_the_task_attack_runs_without_a_planner(table, witness, no_process):
    """Under ``solvable`` the task attack samples its goals and covers them in this process."""
    from advocc_ros.attack import attack

    heatmap, robot, scene, q = table
    result = attack(heatmap, robot, scene.objects, q, scene.goal, 2, 'task', seed=1,
                    goal_policy='solvable', witness=witness)
    assert result.status.ok and result.stats['task_goal_samples'] > 0 and no_process == []
    assert result.solvable.certified, result.solvable.message


@pytest.mark.processes  # a fresh interpreter
def test_the_core_modules_import_no_planner():
    code = ('import sys, advocc_ros.attack, advocc_ros.attack.api, advocc_ros.attack.task\n'
            'print(sorted(m for m in sys.modules if m.startswith(("advocc_ros.planning.worker",'
            ' "advocc_ros.planning.solve", "advocc_ros.planning.pool", "ompl.geometric"))))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]'


_CLI = '''
import json, sys
events = []
def hook(event, args):
    if event in {events!r}:
        events.append([event, repr(args)[:300]])
sys.addaudithook(hook)
from advocc_ros.cli import main
code = main({argv!r})
print('SPAWNED ' + json.dumps(events))
sys.exit(code)
'''


def _cli_spawns(argv, env):
    """(exit code, process starts of ``advocc ARGV``, output) with an audit hook recording
    every process start."""
    script = _CLI.format(events=SPAWN_EVENTS, argv=list(argv))
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         timeout=300, env=env, cwd=REPO)
    line = next(x for x in out.stdout.splitlines() if x.startswith('SPAWNED '))
    return out.returncode, json.loads(line[len('SPAWNED '):]), out


@pytest.mark.processes  # CLI runs
def test_cli_attack_under_paper_starts_no_planner(tmp_path, heatmap_file):
    env = dict(os.environ, ADVOCC_WITNESS_CACHE='off')
    base = ['attack', '--heatmap', str(heatmap_file), '--scene', 'table_pick', '--budget', '2',
            '--method', 'task', '--json']
    code, spawned, out = _cli_spawns(base + ['--policy', 'paper', '--out',
                                             str(tmp_path / 'paper.yaml')], env)
    assert code == 0, out.stderr[-2000:]
    assert spawned == [], spawned
    data = json.loads(out.stdout.split('SPAWNED ')[0])
    assert 'witness_search_ms' not in data['stats'] and data['witness_file'] is None
    # The control: --certify (and the solvable policy) find the witness, in a planning worker,
    # timed apart from the attack's compute time.
    code, spawned, out = _cli_spawns(base + ['--policy', 'paper', '--certify', '--out',
                                             str(tmp_path / 'certify.yaml')], env)
    assert code == 0, out.stderr[-2000:]
    assert any('advocc_ros.planning.worker' in args for _, args in spawned), spawned
    data = json.loads(out.stdout.split('SPAWNED ')[0])
    assert data['stats']['witness_search_ms'] > 0


@pytest.mark.processes  # the witness search (a planning worker)
def test_edge_attack_task_finds_the_witness_only_when_needed(table, monkeypatch):
    import advocc_ros.planning.witness_cache as witness_module
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.edges import attack_task

    heatmap, robot, scene, q = table
    searches = []
    real = witness_module.find_witnesses
    monkeypatch.setattr(witness_module, 'find_witnesses',
                        lambda *a, **k: searches.append(1) or real(*a, **k))
    paper = attack_task(heatmap, robot, scene.objects, q, scene.goal, 2, 'ours')
    assert searches == [] and paper.witness is None
    certified = attack_task(heatmap, robot, scene.objects, q, scene.goal, 2, 'ours',
                            AttackConfig(search_witness=True))
    assert searches == [1] and certified.witness is not None
    assert certified.stats['witness_search_ms'] >= 0
    # A refused task starts no search.
    bad = np.array(q, float)
    bad[3] = 0.5
    refused = attack_task(heatmap, robot, scene.objects, bad, scene.goal, 2, 'ours',
                          goal_policy='solvable')
    assert searches == [1] and refused.status.value == 'invalid_start'
    assert 'panda_joint4 = 0.5' in refused.message
