"""The TrajOpt victim on the real Tesseract 0.5.1 TrajOpt, small scenes, no mocks.

``make install`` installs Tesseract (the ``victims`` extra): without it these tests fail.
"""

import tempfile

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.scene import make_box
from advocc_ros.planning.types import PlanStatus
from advocc_ros.planning.victims import (Task, VictimConfig, first_collision_along,
                                         goal_configurations, make_victim)
from advocc_ros.planning.victims.trajopt import (OptimOutcome, TrajOptConfig, TrajOptSolver,
                                                 initial_guess, snap_ends)

READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


@pytest.fixture(scope='module')
def solver(panda):
    return TrajOptSolver(panda)


def test_tesseract_model_agrees_with_ours(panda, table_scene, solver):
    """Both models use the convex hulls: their verdicts on random configurations agree."""
    solver.set_objects(table_scene.shapes)
    Q = panda.sample_q(np.random.default_rng(1), 300)
    ours = CollisionWorld(panda, table_scene.shapes).collisions_batch(Q)
    theirs = solver.tesseract.collisions(Q)
    assert 0.02 < ours.mean() < 0.9  # the sample exercises both verdicts
    assert (ours == theirs).mean() >= 0.99


def test_loading_the_robot_leaves_no_files_behind(panda, table_scene, tmp_path, monkeypatch):
    """The robot files Tesseract reads are gone once it has loaded them, so a worker that is
    killed leaves nothing in the temporary directory; the loaded model still checks states."""
    from advocc_ros.planning.victims.tesseract_env import TesseractWorld

    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    world = TesseractWorld(panda)
    assert list(tmp_path.iterdir()) == []
    world.set_objects(table_scene.shapes)
    Q = panda.sample_q(np.random.default_rng(2), 50)
    assert (world.collisions(Q) == CollisionWorld(panda, table_scene.shapes)
            .collisions_batch(Q)).mean() >= 0.95


def test_guess_runs_through_the_via_point():
    q0, q1, via = np.zeros(7), np.ones(7), np.full(7, 3.0)
    straight = initial_guess(q0, q1, None, 30)
    assert straight.shape == (30, 7) and np.allclose(straight[[0, -1]], [q0, q1])
    bent = initial_guess(q0, q1, via, 30)
    assert bent.shape == (30, 7) and np.allclose(bent[[0, 15, -1]], [q0, via, q1])


def test_path_ends_snap_to_start_and_goal_within_tolerance():
    """TrajOpt stops 1e-3 rad inside a joint limit: a goal at the limit is reached exactly."""
    q0, q1 = np.zeros(7), np.full(7, 0.5)
    path = initial_guess(q0, q1, None, 5)
    path[-1, 4] -= 1e-3
    tol = TrajOptConfig().endpoint_tol_rad
    snapped = snap_ends(path, q0, q1, tol)
    assert np.array_equal(snapped[-1], q1) and np.array_equal(snapped[1:-1], path[1:-1])
    path[-1, 4] -= 0.01
    assert snap_ends(path, q0, q1, tol) is None


def test_every_goal_configuration_blocked_is_its_own_outcome(panda, solver):
    q_goal = READY.copy()
    q_goal[0] += 1.2
    solver.set_objects(list(make_box('block', panda.ee_pose(q_goal).translation,
                                     (0.2, 0.2, 0.2)).shapes))
    result = solver.plan(READY, np.array([q_goal, q_goal]), 5.0, 0)
    assert result.status == PlanStatus.GOAL_STATE_INVALID
    assert result.stats['outcome'] == OptimOutcome.NO_VALID_GOAL.value
    assert result.stats['goal_configs_valid'] == 0 and not result.stats['attempts']
    assert result.path.shape == (0, 7) and not result.success


def test_start_in_collision_and_an_empty_budget(panda, solver):
    solver.set_objects(list(make_box('block', panda.ee_pose(READY).translation,
                                     (0.1, 0.1, 0.1)).shapes))
    q_goal = READY + 0.3
    result = solver.plan(READY, q_goal[None], 5.0, 0)
    assert result.status == PlanStatus.START_STATE_IN_COLLISION
    solver.set_objects([])
    result = solver.plan(READY, q_goal[None], 1e-6, 0)
    assert result.status == PlanStatus.TIMED_OUT and not result.stats['attempts']


def test_shapes_it_cannot_take_are_named(panda, solver, table_scene):
    import trimesh
    from advocc_ros.model.pose import Pose
    from advocc_ros.model.shapes import make_mesh_shape
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    mesh = make_mesh_shape(box.vertices, box.faces, Pose((0.5, 0.0, 0.5)))
    with pytest.raises(ValueError, match="not 'mesh'"):
        solver.set_objects([mesh])


@pytest.mark.processes
def test_solves_unattacked_table_pick_in_its_worker(panda, table_scene):
    """Through the registry and the worker process, as the evaluation runs it; a rate over
    seeds, every success re-validated here by our exact checker."""
    config = VictimConfig(goal_configs=8)
    q_start = start_configuration(table_scene, panda)
    task = Task(table_scene, q_start, table_scene.goal)
    world = CollisionWorld(panda, table_scene.shapes)
    victim = make_victim('trajopt', config).start()
    try:
        results = [victim.plan(task, 5.0, seed) for seed in range(3)]
    finally:
        victim.close()
    solved = [r for r in results if r.success]
    assert len(solved) >= 2, [r.message for r in results]
    for seed, r in enumerate(results):
        if not r.success:
            continue
        goals = goal_configurations(panda, world, table_scene.goal, 8, seed)
        assert np.allclose(r.path[0], q_start)
        assert np.min(np.abs(goals - r.path[-1]).max(axis=1)) < 1e-6
        assert first_collision_along(world, r.path, config.check_step_rad) == -1
        assert 0 < r.first_solution_s <= 5.0
        assert r.stats['path_length_rad'] > 0 and r.stats['min_clearance_m'] > 0


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match='waypoints'):
        TrajOptConfig(waypoints=2)
    with pytest.raises(ValueError, match='collision_margin_m'):
        TrajOptConfig(collision_margin_m=-0.01)


@pytest.mark.processes
def test_a_box_hidden_from_trajopt_is_caught_by_our_checker(panda):
    """Re-validation: TrajOpt does not see the wall (diagnostic ``hidden_object_ids``) and
    plans straight through it; our checker in the parent reports a model mismatch, not a
    success."""
    from advocc_ros.model.goal import GoalRegion
    from advocc_ros.model.pose import Pose
    from advocc_ros.model.scene import Scene
    q_goal = READY.copy()
    q_goal[0] += 1.5
    wall = make_box('wall', panda.ee_pose((READY + q_goal) / 2).translation, (0.1, 0.1, 0.1))
    T_goal = panda.ee_pose(q_goal)
    goal = GoalRegion(Pose(tuple(T_goal.translation),
                           tuple(pin.Quaternion(T_goal.rotation).coeffs())))
    scene = Scene(objects=(wall,), start=dict(zip(panda.joint_names, READY)), goal=goal)
    task = Task(scene, READY, goal, goal_configs=q_goal[None])
    victim = make_victim('trajopt', VictimConfig(hidden_object_ids=('wall',))).start()
    try:
        result = victim.plan(task, 5.0, 0)
    finally:
        victim.close()
    assert result.status == PlanStatus.MODEL_MISMATCH, result.message
    assert result.stats['outcome'] == 'model_mismatch' and not result.success
