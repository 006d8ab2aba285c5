"""OMPL 2.0.1's planners as victims (``aorrtc``, ``rrtconnect2``): our planning worker in the
OMPL 2 venv, watched like ours, every path re-checked in our model."""

import subprocess

import numpy as np
import pytest

from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.scene import load_scene
from advocc_ros.paths import scene_path
from advocc_ros.planning.types import PlanStatus
from advocc_ros.planning.victims import (Task, first_collision_along, is_outside, is_victim,
                                         make_victim)
from advocc_ros.planning.victims.ompl2 import ompl2_python

BUDGET_S = 2.0


def venv_ompl_version() -> str:
    """What the OMPL 2 venv's own interpreter reports as the version of the OMPL it imports."""
    return subprocess.run(
        [str(ompl2_python()), '-c', 'import ompl, importlib.metadata as m; '
         'print(m.version(ompl.__name__))'],
        capture_output=True, text=True, check=True, timeout=60).stdout.strip()


def test_ompl2_victims_are_registered():
    assert is_victim('aorrtc') and is_outside('aorrtc') and is_outside('rrtconnect2')
    assert not is_outside('rrtconnect')


@pytest.mark.processes
@pytest.mark.timing  # the first solution well inside the budget
@pytest.mark.parametrize('name, scene_name', [('aorrtc', 'table_under_pick'),
                                              ('rrtconnect2', 'table_pick')])
def test_ompl2_victim_plans_and_is_rechecked(name, scene_name, panda):
    scene = load_scene(scene_path(scene_name))
    task = Task(scene, start_configuration(scene, panda), scene.goal)
    world = CollisionWorld(panda, scene.shapes)
    victim = make_victim(name)
    try:
        victim.start(scene)
        results = [victim.plan(task, BUDGET_S, seed) for seed in range(3)]
    finally:
        victim.close()
    version = venv_ompl_version()
    assert version.startswith('2.')
    assert all(r.stats.get('ompl') == version for r in results)
    assert sum(r.success for r in results) >= 2, [r.message for r in results]
    # AORRTC optimizes to its budget; its first solution is marked when OMPL's problem
    # definition first holds one (it never calls isStartGoalPairValid), long before the end.
    assert min(r.first_solution_s for r in results if r.success) < 0.5 * BUDGET_S
    for r in results:
        # AORRTC 2.0.1 answers INVALID_GOAL with a zero-length path at a goal when start and
        # goal connect directly (ompl/ompl#1420): a planning failure, never a success.
        assert r.success or r.status in (PlanStatus.PLANNING_FAILED, PlanStatus.TIMED_OUT)
        if r.success:
            assert np.allclose(r.path[0], task.q_start)
            assert first_collision_along(world, r.path, 0.01) == -1
            assert scene.goal.contains(panda.ee_pose(r.path[-1])
                                       * scene.goal.tool_offset.to_se3())


@pytest.mark.processes
def test_evaluate_aorrtc_reports_both_psrs(table_scene):
    row = evaluate_planner(table_scene, 'aorrtc', 2, BUDGET_S, seed=0)
    assert row['planner'] == 'aorrtc' and row['trials'] == 2
    assert row['no_goal_found'] == 0 and row['psr_given_goals'] == row['psr']
    assert all(a >= 1 for a in row['goal_attempts'])
