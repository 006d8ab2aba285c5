"""Same seed, same answer: seeded attacks do not depend on how busy the machine is."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import planner_goals
from advocc_ros.kinematics.ik import GoalSampler, start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.planning.witness import CACHE_ENV

from conftest import REPO

CLI = [sys.executable, '-m', 'advocc_ros.cli']


def _env():
    env = dict(os.environ)
    env['PYTHONPATH'] = str(REPO) + os.pathsep + env.get('PYTHONPATH', '')
    env[CACHE_ENV] = 'off'  # both runs search their witness: the search is under test too
    return env


def _attack(heatmap, out) -> dict:
    proc = subprocess.run(
        CLI + ['attack', '--method', 'task', '--budget', '5', '--seed', '1', '--json',
               '--no-progress', '--heatmap', str(heatmap), '--scene', 'table_pick',
               '--out', str(out)],
        capture_output=True, text=True, timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def _answer(result: dict) -> dict:
    stats = result['stats']
    return {'boxes': [o['pose']['position'] for o in result['obstacles']],
            'masses': result['masses'], 'goal_valid_fraction': result['goal_valid_fraction'],
            'samples': [stats['task_goal_samples'], stats['task_approach_samples'],
                        stats['goal_samples']]}


@pytest.mark.processes
def test_task_attack_is_the_same_alone_and_beside_two_cpu_hogs(tmp_path, table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap

    heatmap = tmp_path / 'h.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=300), seed=1), heatmap)
    alone = _attack(heatmap, tmp_path / 'alone.yaml')
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(2)]
    try:
        loaded = _attack(heatmap, tmp_path / 'loaded.yaml')
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    assert alone['status'] == 'success' and len(alone['obstacles']) == 5
    assert _answer(loaded) == _answer(alone)


@pytest.fixture(scope='module')
def table(table_scene):
    robot = load_robot(table_scene.robot)
    return robot, CollisionWorld(robot, table_scene.shapes), table_scene


def test_the_goal_sampler_follows_its_seed_not_the_clock(table):
    robot, world, scene = table
    first = planner_goals(robot, scene.goal, world.collisions_batch, 24, seed=5)
    again = planner_goals(robot, scene.goal, world.collisions_batch, 24, seed=5)
    other = planner_goals(robot, scene.goal, world.collisions_batch, 24, seed=6)
    assert first.Q.shape == (24, robot.nq) and first.attempts == again.attempts
    np.testing.assert_array_equal(first.Q, again.Q)
    assert not np.array_equal(first.Q, other.Q)


def test_goal_sampler_is_seeded_when_its_deadline_is_not_hit(table):
    robot, world, scene = table
    q_init = start_configuration(scene, robot)
    assert not world.in_collision(q_init)
    runs = [GoalSampler(robot, world.in_collision, scene.goal,
                        np.random.default_rng(11)).sample(5, float('inf')) for _ in range(2)]
    assert len(runs[0]) == 5
    np.testing.assert_array_equal(np.array(runs[0]), np.array(runs[1]))


def test_negative_message_seeds_are_seeds_too(table_scene, panda):
    """Attack.srv's seed is int64: a negative one is a seed, not an internal error."""
    from advocc_ros.attack import AttackStatus, attack
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap

    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=200), seed=1)
    q = start_configuration(table_scene, panda)
    for method in ('random', 'task'):
        runs = [attack(heatmap, panda, table_scene.objects, q, table_scene.goal, 2, method,
                       seed=-5, certify=False) for _ in range(2)]
        assert runs[0].status == AttackStatus.SUCCESS, runs[0].message
        assert runs[0].centers_m.tolist() == runs[1].centers_m.tolist()
