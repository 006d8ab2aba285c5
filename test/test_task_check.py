"""An invalid task is refused, not scored: a start outside the joint limits or in
collision is refused with the reason by the core check and by every entry point (evaluate,
audit, attack, bench; the services in test_attack_nodes.py and test_planner_shim_node.py)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import REPO

SELF_COLLIDING = [0.0, 0.5, 0.0, -3.0, 0.0, 0.5, 0.785]
"""A Panda configuration within the limits whose hand folds into its base."""
ON_ARM = {'id': 'on_arm', 'type': 'box', 'size': [0.2, 0.2, 0.2],
          'pose': {'position': [0.0, 0.0, 0.6]}}
"""The issue's 0.2 m box on the arm at table_pick's start."""


@pytest.fixture(scope='module')
def bad_scenes(tmp_path_factory):
    """table_pick with panda_joint4 at 0.5 (its limit is -0.07), and with a box on the arm."""
    data = yaml.safe_load((REPO / 'config' / 'scenes' / 'table_pick.yaml').read_text())
    folder = tmp_path_factory.mktemp('bad_scenes')
    limits = dict(data, name='bad_limits', start=dict(data['start'], panda_joint4=0.5))
    collision = dict(data, name='bad_collision', objects=data['objects'] + [ON_ARM])
    paths = {}
    for scene in (limits, collision):
        paths[scene['name']] = folder / f'{scene["name"]}.yaml'
        paths[scene['name']].write_text(yaml.safe_dump(scene))
    return paths


REASONS = {'bad_limits': 'panda_joint4 = 0.5 not in [-3.072, -0.0698]',
           'bad_collision': "with scene object 'on_arm'"}


def _q(scene, robot):
    return np.array([scene.start[j] for j in robot.joint_names])


def test_the_check_names_the_joint_and_the_pairs(panda, table_scene, bad_scenes):
    from advocc_ros.model.scene import load_scene, make_box
    from advocc_ros.model.task_check import TaskProblem, check_task

    q = _q(table_scene, panda)
    assert check_task(panda, table_scene.objects, q, table_scene.goal) is None
    limits = load_scene(bad_scenes['bad_limits'])
    fault = check_task(panda, limits.objects, _q(limits, panda), limits.goal)
    assert fault.problem == TaskProblem.START_INVALID
    assert REASONS['bad_limits'] in fault.message
    collision = load_scene(bad_scenes['bad_collision'])
    fault = check_task(panda, collision.objects, q, collision.goal)
    assert fault.problem == TaskProblem.START_IN_COLLISION
    assert 'in collision with the scene' in fault.message
    assert all(b == "scene object 'on_arm'" for _, b in fault.pairs) and len(fault.pairs) >= 2
    assert {a for a, _ in fault.pairs} >= {'panda_link3_0', 'panda_link4_0'}
    fault = check_task(panda, (), SELF_COLLIDING, table_scene.goal)
    assert fault.problem == TaskProblem.START_IN_COLLISION and 'self collision' in fault.message
    assert all(a.startswith('panda_') and b.startswith('panda_') for a, b in fault.pairs)
    # A box made of two shapes is named with the shape's index.
    two = make_box('pair', (0.0, 0.0, 0.6), (0.2, 0.2, 0.2))
    two = type(two)('pair', two.shapes + make_box('x', (2.0, 2.0, 2.0), (0.1,) * 3).shapes)
    assert "scene object 'pair[0]'" in check_task(panda, (two,), q, None).message
    wrong = check_task(panda, (), np.zeros(6), None)
    assert wrong.problem == TaskProblem.START_INVALID and '7 joint values' in wrong.message
    import dataclasses
    link = check_task(panda, (), q, dataclasses.replace(table_scene.goal, link='tool0'))
    assert link.problem == TaskProblem.GOAL_INVALID and "'tool0'" in link.message


def test_the_shipped_scenes_are_valid_tasks():
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import load_scene
    from advocc_ros.model.task_check import check_task

    for path in sorted((REPO / 'config' / 'scenes').glob('*.yaml')):
        scene = load_scene(path)
        robot = load_robot(scene.robot)
        assert check_task(robot, scene.objects, start_configuration(scene, robot),
                          scene.goal) is None, path.name


def _cli(*argv, timeout=240):
    return subprocess.run([sys.executable, '-m', 'advocc_ros.cli', *argv], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO,
                          env=dict(os.environ, ADVOCC_WITNESS_CACHE='off'))


@pytest.mark.processes  # CLI runs
@pytest.mark.parametrize('name', ['bad_limits', 'bad_collision'])
def test_evaluate_refuses_an_invalid_task(bad_scenes, name):
    """Was: '2 of 2 trials were internal errors', PSR N/A, exit 0."""
    out = _cli('evaluate', '--scene', str(bad_scenes[name]), '--trials', '2', '--time', '1')
    assert out.returncode == 2, out.stdout + out.stderr
    assert 'the task is refused' in out.stderr and REASONS[name] in out.stderr
    assert 'internal error' not in out.stderr and 'PSR' not in out.stdout


@pytest.mark.processes  # CLI runs
@pytest.mark.parametrize('name', ['bad_limits', 'bad_collision'])
def test_audit_and_attack_refuse_an_invalid_task(bad_scenes, heatmap_file, tmp_path, name):
    audit = _cli('audit', '--scene', str(bad_scenes[name]), '--heatmap', str(heatmap_file),
                 '--max-budget', '1', '--trials', '1', '--time', '1',
                 '--out', str(tmp_path / 'audit'))
    assert audit.returncode == 2, audit.stdout + audit.stderr
    assert REASONS[name] in audit.stderr and not (tmp_path / 'audit').exists()
    for policy in ('paper', 'solvable'):
        attack = _cli('attack', '--heatmap', str(heatmap_file), '--scene',
                      str(bad_scenes[name]), '--budget', '1', '--method', 'task', '--policy',
                      policy, '--out', str(tmp_path / 'obs.yaml'))
        assert attack.returncode == 2, attack.stdout + attack.stderr
        assert REASONS[name] in attack.stderr and not (tmp_path / 'obs.yaml').exists()


@pytest.mark.processes  # CLI runs
def test_bench_refuses_an_invalid_task_before_any_work(bad_scenes, tmp_path):
    scenes = f'table_pick,{bad_scenes["bad_collision"]}'
    out = _cli('bench', '--profile', 'quick', '--scenes', scenes,
               '--methods', 'random', '--budgets', '1', '--trials', '1',
               '--out', str(tmp_path / 'run'))
    assert out.returncode == 2, out.stdout + out.stderr
    assert 'the task is refused' in out.stderr and REASONS['bad_collision'] in out.stderr
    assert not (tmp_path / 'run' / 'heatmaps').exists()
    assert not (tmp_path / 'run' / 'records.jsonl').exists()


def test_attack_core_names_the_pair(panda, table_scene, heatmap_file):
    from advocc_ros.attack import AttackStatus, attack
    from advocc_ros.heatmap import load_heatmap

    result = attack(load_heatmap(heatmap_file), panda, table_scene.objects, SELF_COLLIDING,
                    table_scene.goal, 1)
    assert result.status == AttackStatus.START_IN_COLLISION
    assert 'self collision: panda_link' in result.message and not result.obstacles
    assert json.dumps(result.to_json())  # errors are data
