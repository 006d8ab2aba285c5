"""Planning core: real OMPL planners in a worker process, goal regions, statuses, watchdog."""

import dataclasses
import time

import numpy as np
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.evaluation.metrics import densify
from advocc_ros.planning.worker import Planner
from advocc_ros.planning.types import PlanningConfig, PlanStatus, planner_class_name
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose
from advocc_ros.model.scene import SceneObject, make_box
from advocc_ros.model.shapes import Shape

# workers; planners against a 1 s budget, timed: no other test runs meanwhile
pytestmark = [pytest.mark.processes, pytest.mark.timing]

BUDGET = 1.0


@pytest.fixture(scope='module')
def open_scene(table_scene):
    """table_pick with the table only: the goal region is reachable and unobstructed."""
    return dataclasses.replace(table_scene, objects=tuple(
        o for o in table_scene.objects if o.id == 'table'))


@pytest.fixture(scope='module')
def planner(open_scene):
    with Planner(open_scene) as p:
        yield p.start()


def _walls_around(goal: GoalRegion, inner=0.09, thick=0.02, z_low=0.10, z_high=0.62,
                  hole=0.0):
    """4 walls + a roof around the goal region, standing on the table.

    ``hole`` > 0 leaves a square hole of that half-width in the roof: too narrow for the hand to
    pass; about 1 in 100 IK goal configurations threads the wrist through it collision-free, so
    the planners sometimes get to search and must then fail in the search.
    """
    cx, cy, _ = goal.center.position_m
    h = z_high - z_low
    zc = z_low + h / 2
    off = inner + thick / 2
    outer = inner + thick
    walls = (
        make_box('wall_px', (cx + off, cy, zc), (thick, 2 * outer, h)),
        make_box('wall_nx', (cx - off, cy, zc), (thick, 2 * outer, h)),
        make_box('wall_py', (cx, cy + off, zc), (2 * inner, thick, h)),
        make_box('wall_ny', (cx, cy - off, zc), (2 * inner, thick, h)))
    z = z_high + thick / 2
    if hole <= 0:
        return walls + (make_box('roof', (cx, cy, z), (2 * outer, 2 * outer, thick)),)
    w = outer - hole
    return walls + (
        make_box('roof_px', (cx + hole + w / 2, cy, z), (w, 2 * outer, thick)),
        make_box('roof_nx', (cx - hole - w / 2, cy, z), (w, 2 * outer, thick)),
        make_box('roof_py', (cx, cy + hole + w / 2, z), (2 * hole, w, thick)),
        make_box('roof_ny', (cx, cy - hole - w / 2, z), (2 * hole, w, thick)))


def _check_path(robot, world, path, q0, goal):
    assert path.shape[1] == robot.nq and len(path) >= 2
    np.testing.assert_allclose(path[0], q0, atol=1e-9)
    T = robot.ee_pose(path[-1]) if goal.link == robot.spec.ee_link else None
    assert goal.contains(T * goal.tool_offset.to_se3())
    dense = densify(path, 0.01)
    assert not world.collisions_batch(dense).any(), 'trajectory collides between waypoints'
    assert np.all(dense >= robot.lower - 1e-9) and np.all(dense <= robot.upper + 1e-9)


@pytest.mark.parametrize('planner_id', ['rrtconnect', 'prmstar', 'bkpiece1'])
def test_planners_reach_goal_region(planner, open_scene, planner_id):
    robot = planner.robot
    world = CollisionWorld(robot, open_scene.shapes)
    q0 = start_configuration(open_scene, robot)
    results = [planner.plan(q0, open_scene.goal, planner_id, BUDGET, seed) for seed in range(4)]
    ok = [r for r in results if r.success]
    assert len(ok) >= 3, [r.message for r in results]
    for r in ok:
        _check_path(robot, world, r.path, q0, open_scene.goal)
        assert r.planning_time_s < BUDGET + 0.5
        assert r.stats['goal_configs'] >= 1


@pytest.mark.parametrize('planner_id', ['rrtconnect', 'prmstar', 'bkpiece1'])
def test_planners_fail_when_goal_walled_in(planner, open_scene, planner_id):
    """A closed box fails in goal sampling; so does (mostly) a roof with a wrist-sized hole."""
    closed = open_scene.with_objects(_walls_around(open_scene.goal))
    chimney = open_scene.with_objects(_walls_around(open_scene.goal, inner=0.16, z_high=0.44,
                                                    hole=0.08))
    q0 = start_configuration(open_scene, planner.robot)
    config = planner.config
    planner.config = dataclasses.replace(config, ik_time_fraction=0.5)
    try:
        planner.set_scene(closed)
        boxed = [planner.plan(q0, open_scene.goal, planner_id, BUDGET, seed) for seed in range(2)]
        planner.set_scene(chimney)
        caged = [planner.plan(q0, open_scene.goal, planner_id, BUDGET, seed) for seed in range(2)]
    finally:
        planner.set_scene(open_scene)
        planner.config = config
    for r in boxed:
        assert r.status == PlanStatus.GOAL_IN_COLLISION, r.message
    for r in caged:
        assert r.status in (PlanStatus.GOAL_IN_COLLISION, PlanStatus.TIMED_OUT,
                            PlanStatus.PLANNING_FAILED), r.message
        assert len(r.path) == 0


def test_prmstar_is_real_and_honours_budget(planner, open_scene):
    """PRM* optimizes until the budget ends (like MoveIt), and returns close to it."""
    q0 = start_configuration(open_scene, planner.robot)
    t0 = time.monotonic()
    r = planner.plan(q0, open_scene.goal, 'prmstar', BUDGET, 7)
    wall = time.monotonic() - t0
    assert r.stats.get('planner') == 'PRMstar'
    assert wall < BUDGET + 0.5, wall
    assert r.success and r.stats['solve_time_s'] > 0.5 * BUDGET


def test_no_ik_solution_for_unreachable_region(planner, open_scene):
    far = GoalRegion(Pose((2.0, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0)), (0.02, 0.02, 0.02),
                     (0.1, 0.1, 0.1))
    q0 = start_configuration(open_scene, planner.robot)
    r = planner.plan(q0, far, 'rrtconnect', BUDGET, 0)
    assert r.status == PlanStatus.NO_IK_SOLUTION, r.message
    assert r.planning_time_s <= PlanningConfig().ik_time_fraction * BUDGET + 0.1


def test_bad_requests_get_clear_statuses(planner, open_scene):
    robot = planner.robot
    q0 = start_configuration(open_scene, robot)
    goal = open_scene.goal
    nan = q0.copy()
    nan[2] = np.nan
    outside = q0.copy()
    outside[3] = 0.5  # panda_joint4 upper limit is -0.0698
    cases = [
        (planner.plan(q0, goal, 'no_such_planner', BUDGET), PlanStatus.UNKNOWN_METHOD),
        (planner.plan(nan, goal, 'rrtconnect', BUDGET), PlanStatus.INVALID_REQUEST),
        (planner.plan(q0[:5], goal, 'rrtconnect', BUDGET), PlanStatus.INVALID_ROBOT_STATE),
        (planner.plan(outside, goal, 'rrtconnect', BUDGET), PlanStatus.INVALID_ROBOT_STATE),
        (planner.plan(q0, goal, 'rrtconnect', -1.0), PlanStatus.INVALID_REQUEST),
        (planner.plan(q0, goal, 'rrtconnect', float('inf')), PlanStatus.INVALID_REQUEST),
        (planner.plan(q0, dataclasses.replace(goal, link='no_link'), 'rrtconnect', BUDGET),
         PlanStatus.INVALID_GOAL_CONSTRAINTS),
    ]
    for result, status in cases:
        assert result.status == status, result.message
        assert result.message
    assert planner_class_name('RRTConnectkConfigDefault') == 'RRTConnect'


def test_start_in_collision(planner, open_scene):
    robot = planner.robot
    q0 = start_configuration(open_scene, robot)
    hand = robot.ee_pose(q0).translation
    scene = open_scene.with_objects([SceneObject('on_hand', (Shape(
        'box', (0.1, 0.1, 0.1), Pose(tuple(hand.tolist()))),))])
    planner.set_scene(scene)
    try:
        r = planner.plan(q0, open_scene.goal, 'rrtconnect', BUDGET)
    finally:
        planner.set_scene(open_scene)
    assert r.status == PlanStatus.START_STATE_IN_COLLISION


def test_watchdog_kills_an_overrun_and_recovers(open_scene):
    with Planner(open_scene) as planner:
        planner.start()
        pid = planner.worker_pid
        t0 = time.monotonic()
        r = planner.stall(30.0, watchdog_s=1.0)
        assert time.monotonic() - t0 < 3.0
        assert r.status == PlanStatus.TIMED_OUT and r.stats.get('watchdog')
        assert planner.worker_pid is None and planner.restarts == 1
        q0 = start_configuration(open_scene, planner.robot)
        r = planner.plan(q0, open_scene.goal, 'rrtconnect', BUDGET, 1)
        assert r.success, r.message
        assert planner.worker_pid not in (None, pid)


def test_worker_ignores_a_checkout_in_the_working_directory(open_scene, tmp_path, monkeypatch):
    """A node started inside another checkout must not plan with that checkout's code."""
    fake = tmp_path / 'advocc_ros'
    fake.mkdir()
    (fake / '__init__.py').write_text('raise ImportError("the cwd\'s checkout was imported")\n')
    monkeypatch.chdir(tmp_path)
    with Planner(open_scene) as planner:
        planner.start()
        q0 = start_configuration(open_scene, planner.robot)
        r = planner.plan(q0, open_scene.goal, 'rrtconnect', BUDGET, 1)
    assert r.success, r.message


def test_a_solution_through_an_obstacle_is_refused_as_moveit_does(open_scene, panda):
    """With a motion check far coarser than the interpolation, RRTConnect connects start and
    goal straight through a thin plate; the shim validates the interpolated solution (as
    MoveIt's ValidateSolution adapter does) and answers INVALID_MOTION_PLAN, a planner
    failure, never a success that collides."""
    from advocc_ros.formats.mbm_request import goal_region_at
    from advocc_ros.model.scene import Scene

    q0 = start_configuration(open_scene, panda)
    q_goal = q0.copy()
    q_goal[0] += 1.5  # the same pose, swung 1.5 rad about the base
    goal = goal_region_at(panda, dict(zip(panda.joint_names, q_goal)))
    angle = 0.75  # a radial plate halfway along the swing, clear of start and goal
    plate = SceneObject('plate', (Shape('box', (0.3, 0.01, 0.3), Pose(
        (0.32 * np.cos(angle), 0.32 * np.sin(angle), 0.6),
        (0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)))),))
    scene = Scene(open_scene.objects + (plate,), dict(open_scene.start), goal,
                  open_scene.robot, 'plate')
    world = CollisionWorld(panda, scene.shapes)
    assert not world.in_collision(q0) and not world.in_collision(q_goal)
    coarse = PlanningConfig(motion_step_rad=3.0)
    with Planner(scene, coarse) as planner:
        results = [planner.plan(q0, goal, 'rrtconnect', BUDGET, seed) for seed in range(3)]
    assert any(r.status == PlanStatus.INVALID_MOTION_PLAN for r in results), \
        [r.message for r in results]
    for r in results:
        if r.status == PlanStatus.INVALID_MOTION_PLAN:
            assert 'in collision' in r.message and len(r.path) == 0
        if r.success:
            assert not world.collisions_batch(r.path).any()


def test_worker_overhead_is_small(planner, open_scene):
    q0 = start_configuration(open_scene, planner.robot)
    overheads = [planner.plan(q0, open_scene.goal, 'rrtconnect', BUDGET, s).stats['overhead_s']
                 for s in range(3)]
    assert np.median(overheads) < 0.05, overheads


def test_planner_shim_yaml_matches_config_defaults():
    """config/planner_shim.yaml and PlanningConfig must not drift apart."""
    import pathlib

    import yaml

    path = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'planner_shim.yaml'
    params = yaml.safe_load(path.read_text())['/planner_shim']['ros__parameters']
    defaults = dataclasses.asdict(PlanningConfig())
    shared = set(params) & set(defaults)
    assert len(shared) >= 8
    for key in shared:
        assert params[key] == defaults[key], key


@pytest.mark.parametrize('planner_id', ['rrtconnect', 'prmstar', 'bkpiece1'])
def test_first_solution_time_is_recorded(planner, open_scene, planner_id):
    """Every success says when its first exact solution existed; PRM* runs on to the budget
    after it, the others stop there (the rest is simplification)."""
    q0 = start_configuration(open_scene, planner.robot)
    results = [planner.plan(q0, open_scene.goal, planner_id, BUDGET, seed) for seed in range(3)]
    ok = [r for r in results if r.success]
    assert len(ok) >= 2, [r.message for r in results]
    for r in ok:
        first = r.first_solution_s
        assert r.stats['ik_time_s'] < first <= r.planning_time_s, (first, r.stats)
        if planner_id == 'prmstar':
            assert first < 0.7 * r.planning_time_s, (first, r.planning_time_s)
    failed = planner.plan(q0, open_scene.goal, planner_id, 0.001, 0)
    assert not failed.success and failed.first_solution_s is None
