"""Goal sampling with its IK in worker processes returns the one-process set, bit for bit, and
the judge's goal set falls back to one process when workers cannot start."""

import dataclasses

import numpy as np
import pytest

from advocc_ros.attack import goals
from advocc_ros.kinematics import goal_workers
from advocc_ros.kinematics.goal_workers import sample_goal_configurations
from advocc_ros.kinematics.ik import GoalSampler
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot

pytestmark = pytest.mark.processes


@pytest.fixture(scope='module')
def task(table_scene):
    robot = load_robot(table_scene.robot)
    return robot, CollisionWorld(robot, table_scene.shapes), table_scene.goal


def _run(task, goal, workers, n=10, max_attempts=80):
    robot, world, _ = task
    sampler = GoalSampler(robot, world.in_collision, goal, np.random.default_rng(3))
    found = sample_goal_configurations(sampler, n, max_attempts, workers)
    return np.array(found).reshape(-1, robot.nq), (sampler.converged, sampler.colliding)


def test_workers_find_the_one_process_set(task):
    one, counts_one = _run(task, task[2], workers=1)
    two, counts_two = _run(task, task[2], workers=2)
    assert len(one) == 10
    np.testing.assert_array_equal(two, one)
    assert counts_two == counts_one


def test_a_seeded_goal_too(task):
    """Seeds, walks near them (normal draws) and random-seed IK interleave in one stream."""
    robot, _, goal = task
    first, _ = _run(task, goal, workers=1, n=2)
    seeded = dataclasses.replace(goal, seed_joints=tuple(robot.joint_names),
                                 seeds=tuple(map(tuple, first)) + ((0.0,) * robot.nq,))
    one, counts_one = _run(task, seeded, workers=1, n=12)
    two, counts_two = _run(task, seeded, workers=2, n=12)
    np.testing.assert_array_equal(two, one)
    assert counts_two == counts_one
    np.testing.assert_array_equal(one[:2], first)


def test_the_attempt_budget_bounds_the_workers_too(task):
    one, _ = _run(task, task[2], workers=1, n=1000, max_attempts=7)
    two, _ = _run(task, task[2], workers=2, n=1000, max_attempts=7)
    np.testing.assert_array_equal(two, one)


def test_workers_that_cannot_start_leave_the_set_to_one_process(task, monkeypatch, caplog):
    robot, world, goal = task

    def broken(*args, **kwargs):
        raise OSError('no processes here')

    monkeypatch.setattr(goals, 'PARALLEL_MIN_SAMPLES', 4)
    monkeypatch.setattr(goal_workers.concurrent.futures, 'ProcessPoolExecutor', broken)
    got = goals._sample_goals(robot, world, goal, 6, goals.SELECTION_SEED, workers=2)
    np.testing.assert_array_equal(got, goals._sample_goals(robot, world, goal, 6,
                                                           goals.SELECTION_SEED))
    assert 'worker processes failed (no processes here)' in caplog.text


def test_the_edges_sample_the_judging_sets_the_core_then_reads(task, table_scene,
                                                               monkeypatch):
    """``judge_goal_sets`` (the edges, workers) leaves the sets the core asks for cached:
    the core samples nothing and starts no process."""
    from advocc_ros.attack.edges import judge_goal_sets
    from advocc_ros.model.cache import clear_task_caches

    robot, _, goal = task
    objects = table_scene.objects
    monkeypatch.setattr(goals, 'PARALLEL_MIN_SAMPLES', 8)
    monkeypatch.setattr(goals, 'END_SAMPLES', 16)
    clear_task_caches()
    with goals.sampled_afresh():
        assert judge_goal_sets(robot, objects, goal, 24, ends=2) > 0.0
        monkeypatch.setattr(goals, '_sample_goals', lambda *a: pytest.fail('sampled again'))
        assert len(goals.selection_goal_samples(robot, objects, goal, 24).Q) == 24
        assert len(goals.rare_goal_configurations(robot, objects, goal, 2)) == 2
    clear_task_caches()
