"""Victims behind one protocol: the registry, our OMPL planners with a goal list, and the real
MPlib (its own venv and worker): plans, goal lists invalid in its model, re-validation of its
paths in our model, a dead worker."""

import numpy as np
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.scene import make_box
from advocc_ros.planning.types import PlanStatus
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.planning.worker import FAULT_ENV
from advocc_ros.planning.victims import (Task, VictimConfig, first_collision_along,
                                         goal_configurations, is_outside, is_victim,
                                         make_victim, victim_names)

BUDGET_S = 2.0
THROUGH_TABLE = np.array([0.0, 1.5, 0.0, -0.5, 0.0, 1.0, 0.0])
"""A Panda configuration whose arm is in table_pick's table."""


@pytest.fixture(scope='module')
def task(table_scene, panda):
    return Task(table_scene, start_configuration(table_scene, panda), table_scene.goal)


@pytest.fixture(scope='module')
def mplib():
    victim = make_victim('mplib')
    yield victim
    victim.close()


def _in_goal(panda, goal, q) -> bool:
    return goal.contains(panda.ee_pose(q) * goal.tool_offset.to_se3())


def test_registry_names_victims():
    assert is_victim('rrtconnect') and is_victim('PRMstar') and is_victim('mplib')
    assert is_outside('mplib') and not is_outside('rrtconnect')
    assert 'mplib' in victim_names() and not is_victim('no_such_planner')
    with pytest.raises(ValueError, match='unknown planner .*mplib'):
        make_victim('no_such_planner')


def test_goal_list_is_the_same_for_every_victim(panda, table_scene):
    world = CollisionWorld(panda, table_scene.shapes)
    a = goal_configurations(panda, world, table_scene.goal, 8, seed=5)
    b = goal_configurations(panda, world, table_scene.goal, 8, seed=5)
    assert len(a) == 8 and np.array_equal(a, b)
    assert not world.collisions_batch(a).any()
    assert all(_in_goal(panda, table_scene.goal, q) for q in a)


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_ompl_victim_plans_to_the_goal_list(task, panda):
    victim = make_victim('rrtconnect', VictimConfig(goal_configs=8, ompl_goal_list=True))
    try:
        victim.start(task.scene)
        results = [victim.plan(task, BUDGET_S, seed) for seed in range(3)]
        assert sum(r.success for r in results) >= 2, [r.message for r in results]
        for r in results:
            assert r.stats['goal_list'] == 8 and r.stats['goal_list_valid'] == 8
        # A goal list that is all in collision in our model is its own failure mode.
        blocked = Task(task.scene, task.q_start, task.goal,
                       goal_configs=np.tile(THROUGH_TABLE, (3, 1)))
        res = victim.plan(blocked, BUDGET_S, 0)
        assert res.status == PlanStatus.GOAL_STATE_INVALID, res.message
    finally:
        victim.close()


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_mplib_plans_the_unattacked_task(mplib, task, panda, table_scene):
    world = CollisionWorld(panda, table_scene.shapes)
    results = [mplib.plan(task, BUDGET_S, seed) for seed in range(4)]
    assert sum(r.success for r in results) >= 3, [r.message for r in results]
    for r in results:
        if r.success:
            assert np.allclose(r.path[0], task.q_start)
            assert _in_goal(panda, task.goal, r.path[-1])
            assert first_collision_along(world, r.path, 0.01) == -1
            assert 0 < r.first_solution_s <= BUDGET_S
            assert r.stats['goal_configs'] == VictimConfig().goal_configs
    # MPlib's own checker agrees on the start (free) and on a configuration through the table.
    assert world.in_collision(THROUGH_TABLE)
    assert mplib.check(task, np.stack([task.q_start, THROUGH_TABLE])).tolist() == [False, True]


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_mplib_goal_list_invalid_in_its_model(mplib, task, panda, table_scene):
    """Goals valid without a box, handed over with the box on them: MPlib's own model refuses
    every one, which is its own outcome, not a planning failure."""
    world = CollisionWorld(panda, table_scene.shapes)
    goals = goal_configurations(panda, world, table_scene.goal, 8, seed=0)
    boxed = table_scene.with_objects([make_box('block', table_scene.goal.center.position_m,
                                               (0.12, 0.12, 0.12))])
    res = mplib.plan(Task(boxed, task.q_start, task.goal, goal_configs=goals), BUDGET_S, 0)
    assert res.status == PlanStatus.GOAL_STATE_INVALID, res.message
    assert res.stats['goal_configs_valid_victim'] == 0 and len(res.path) == 0


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_revalidation_catches_a_box_hidden_from_mplib(task, panda, table_scene):
    """A box our model has and MPlib does not see: its paths through it are MODEL_MISMATCH,
    never successes."""
    p_start = panda.ee_pose(task.q_start).translation
    mid = (p_start + np.asarray(table_scene.goal.center.position_m)) / 2
    walled = table_scene.with_objects([make_box('wall', mid, (0.12, 0.12, 0.12))])
    world = CollisionWorld(panda, walled.shapes)
    goals = goal_configurations(panda, world, walled.goal, 16, seed=0)
    assert len(goals)
    victim = make_victim('mplib', VictimConfig(hidden_object_ids=('wall',)))
    try:
        hidden = Task(walled, task.q_start, task.goal, goal_configs=goals)
        results = [victim.plan(hidden, BUDGET_S, seed) for seed in range(4)]
    finally:
        victim.close()
    statuses = [r.status for r in results]
    assert statuses.count(PlanStatus.MODEL_MISMATCH) >= 2, [r.message for r in results]
    for r in results:
        if r.success:
            assert first_collision_along(world, r.path, 0.01) == -1


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_mplib_dead_worker_is_an_internal_error(task, monkeypatch):
    """A worker that dies mid-request (it SIGKILLs itself on seed 77) or raises is an internal
    error, never a planning outcome; a fresh worker serves the next request."""
    monkeypatch.setenv(FAULT_ENV, 'kill:77')
    victim = make_victim('mplib')
    try:
        res = victim.plan(task, BUDGET_S, 77)
        assert res.status == PlanStatus.INTERNAL_ERROR, res.message
        assert 'MPlib worker was killed by SIGKILL' in res.message
        assert victim.plan(task, BUDGET_S, 1).success
    finally:
        victim.close()


@pytest.mark.processes
@pytest.mark.timing  # plans within a budget and a watchdog
def test_evaluate_runs_mplib_like_our_planners(table_scene):
    """``advocc evaluate --planner mplib``'s runner: the same records and table row."""
    from advocc_ros.evaluation.runner import evaluate_planner

    row = evaluate_planner(table_scene, 'mplib', trials=3, time_budget_s=BUDGET_S, seed=0)
    assert row['planner'] == 'mplib' and row['trials'] == 3 and row['internal_errors'] == 0
    assert row['psr'] >= 2 / 3, [r['message'] for r in row['records']]
    assert set(row['failures']) >= {'goal invalid for victim', 'model mismatch'}
    ok = [r for r in row['records'] if r['success']]
    assert all(r['min_clearance_rad'] is not None and r['first_solution_s'] > 0 for r in ok)


def test_bench_takes_victims_by_name():
    from advocc_ros.bench.protocol import BenchConfig, BenchError

    cfg = BenchConfig(planners=('rrtconnect', 'mplib'), methods=('task',))
    assert cfg.planners == ('rrtconnect', 'mplib')
    with pytest.raises(BenchError, match="unknown \\['nosuch'\\]"):
        BenchConfig(planners=('nosuch',))
    with pytest.raises(BenchError, match='pfa\\+\\+:mplib'):  # PFA++ queries our planners only
        BenchConfig(planners=('rrtconnect', 'mplib'), methods=('task', 'pfa++'))


@pytest.mark.processes
def test_mplib_sees_our_shapes_where_we_do(mplib, task, panda, table_scene):
    """Rotated boxes, a lying cylinder, a sphere and a mesh arrive in MPlib's world where they
    are in ours: over random configurations, MPlib's verdicts differ from ours only within a
    centimetre of contact (its meshes vs our hulls), never far from it."""
    import trimesh

    from advocc_ros.model.pose import Pose
    from advocc_ros.model.scene import SceneObject
    from advocc_ros.model.shapes import Shape, make_mesh_shape

    def tilt(axis, deg):  # quaternion [x, y, z, w]; no symmetry of a box hides a wrong order
        half = np.radians(deg) / 2
        return tuple(np.sin(half) * np.asarray(axis) / np.linalg.norm(axis)) + (np.cos(half),)

    mesh = trimesh.creation.box(extents=(0.25, 0.1, 0.2))
    mesh.apply_translation((0.12, 0.0, 0.05))  # off its frame's origin: the rotation moves it
    extra = [
        SceneObject('slab', (Shape('box', (0.3, 0.05, 0.3),
                                   Pose((0.35, 0.25, 0.5), tilt((1, 1, 0), 50))),)),
        SceneObject('pipe', (Shape('cylinder', (0.5, 0.04),
                                   Pose((0.3, -0.3, 0.6), tilt((0, 1, 1), 70))),)),
        SceneObject('mesh', (make_mesh_shape(mesh.vertices, mesh.faces,
                                             Pose((-0.3, 0.3, 0.5), tilt((1, 0, 1), 60))),))]
    scene = table_scene.with_objects(extra)
    world = CollisionWorld(panda, scene.shapes)
    Q = panda.sample_q(np.random.default_rng(0), 400)
    theirs = mplib.check(Task(scene, task.q_start, task.goal), Q)
    ours = world.collisions_batch(Q)
    near = np.array([world.scene_distance(q, upto_m=0.01) < 0.01 for q in Q])
    assert theirs.sum() >= 40 and (theirs & ~ours).sum() == (theirs & ~ours & near).sum()
    far_free = ~ours & ~near
    assert far_free.sum() >= 40 and not theirs[far_free].any()
    assert (theirs == ours).mean() > 0.9
