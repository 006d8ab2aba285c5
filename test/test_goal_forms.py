"""Goal forms: a MotionBenchMaker joint goal as the configuration itself (``joint``, the default)
or as the paper's region around its hand pose (``region``), through loading, the task check,
planning, the attack and the export."""

import pathlib

import numpy as np
import pytest

from advocc_ros.formats.mbm_export import request_data
from advocc_ros.formats.mbm_request import load_request
from advocc_ros.formats.mbm_scene import load_any_scene
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import make_box
from advocc_ros.model.task_check import TaskProblem, check_task

REAL = pathlib.Path(__file__).parent / 'data' / 'mbm_real'


def _problem(family: str, form: str | None = None):
    folder = REAL / f'{family}_panda'
    scene = load_any_scene(folder / 'scene0001.yaml', folder / 'request0001.yaml',
                           goal_form=form)
    robot = load_robot(scene.robot)
    return scene, robot, start_configuration(scene, robot)


def _request_goal(family: str, robot) -> np.ndarray:
    request = load_request(REAL / f'{family}_panda' / 'request0001.yaml', robot)
    return np.array([request.goal[j] for j in robot.joint_names])


def test_a_joint_goal_request_is_the_configuration_itself_unless_asked_for_a_region():
    scene, robot, _ = _problem('box')
    assert scene.goal.form == 'joint' and scene.goal.is_joint
    q_goal = _request_goal('box', robot)
    assert np.array_equal(scene.goal.configuration(robot.joint_names), q_goal)
    region, _, _ = _problem('box', 'region')
    assert region.goal.form == 'region' and not region.goal.is_joint
    assert region.goal.position_tolerance_m == (0.02, 0.02, 0.02)
    with pytest.raises(SceneError, match='region, not a joint'):
        region.goal.configuration(robot.joint_names)


def test_the_form_is_part_of_the_goal_data_and_checked():
    scene, robot, _ = _problem('box')
    data = scene.goal.to_data()
    assert data['form'] == 'joint'
    assert GoalRegion.from_data(data) == scene.goal
    assert 'form' not in _problem('box', 'region')[0].goal.to_data()  # region files unchanged
    with pytest.raises(SceneError, match='goal.form'):
        GoalRegion.from_data(dict(data, form='pose'))
    with pytest.raises(SceneError, match='the one seed'):
        GoalRegion.from_data(dict(data, seeds=[]))


def test_the_joint_form_needs_a_joint_goal():
    with pytest.raises(SceneError, match='joint form needs a request with a joint goal'):
        load_any_scene('table_pick', goal_form='joint')
    assert load_any_scene('table_pick', goal_form='region').goal.form == 'region'


def test_a_joint_goal_touching_the_scene_is_refused_with_its_pairs():
    """cage 0001's goal closes the fingers on the cube once they are clipped into the URDF's
    limits: in the joint form the task has no solution, and the check says why."""
    scene, robot, q_init = _problem('cage')
    fault = check_task(robot, scene.objects, q_init, scene.goal)
    assert fault is not None and fault.problem == TaskProblem.GOAL_IN_COLLISION
    assert 'goal configuration is in collision with the scene' in fault.message
    assert any('finger' in a for a, _ in fault.pairs)
    region, _, _ = _problem('cage', 'region')
    assert check_task(robot, region.objects, q_init, region.goal) is None
    box_scene, box_robot, box_start = _problem('box')
    assert check_task(box_robot, box_scene.objects, box_start, box_scene.goal) is None


def test_a_joint_export_holds_exactly_its_goal_and_reads_back_the_same():
    scene, robot, _ = _problem('box')
    goals = request_data(scene, robot)['goal_constraints']
    assert len(goals) == 1 and not goals[0]['position_constraints']
    values = {c['joint_name']: c['position'] for c in goals[0]['joint_constraints']}
    q_goal = scene.goal.configuration(robot.joint_names)
    assert [values[j] for j in robot.joint_names] == q_goal.tolist()


def test_a_region_export_leaves_out_a_seed_the_boxes_block(panda):
    scene, robot, _ = _problem('box', 'region')
    free = request_data(scene, robot)['goal_constraints']
    assert len(free) == 2 and free[1]['joint_constraints']  # the region, then its seed
    seed = np.array(scene.goal.seeds[0])
    hand = robot.ee_pose(seed).translation
    blocked = scene.with_objects((make_box('adv_0', hand, (0.05, 0.05, 0.05)),))
    assert CollisionWorld(robot, blocked.shapes).in_collision(seed)
    goals = request_data(blocked, robot)['goal_constraints']
    assert len(goals) == 1 and goals[0]['position_constraints']


def test_a_plan_to_a_joint_goal_ends_exactly_there():
    from advocc_ros.planning.solve import solve
    from advocc_ros.planning.types import PlanningConfig

    scene, robot, q_init = _problem('box')
    world = CollisionWorld(robot, scene.shapes)
    q_goal = scene.goal.configuration(robot.joint_names)
    result = solve(robot, world, q_init, scene.goal, 'rrtconnect', 10.0, 3,
                   PlanningConfig(simplify=False))
    assert result.success, result.message
    assert np.abs(result.path[-1] - q_goal).max() <= 1e-9
    assert result.stats['goal_list'] == 1


@pytest.fixture(scope='module')
def box_heatmap():
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap
    scene, _, _ = _problem('box')
    return build_heatmap(scene, HeatmapConfig(samples=400, robot_only=True), seed=1)


def test_the_joint_form_attack_keeps_the_goal_configuration_clear(box_heatmap):
    """No witness (the paper's policy): the boxes still keep the certificate's guard margin from
    the goal's whole body."""
    from advocc_ros.attack import AttackConfig, attack
    from advocc_ros.planning.certificate import CertificateConfig

    scene, robot, q_init = _problem('box')
    result = attack(box_heatmap, robot, scene.objects, q_init, scene.goal, 8, 'task',
                    AttackConfig(), certify=False)
    assert result.status.ok, result.message
    assert result.goal_form == 'joint' and result.to_json()['goal_form'] == 'joint'
    assert result.stats['task_goal_samples'] == 0 and result.stats['task_approach_samples'] > 0
    q_goal = scene.goal.configuration(robot.joint_names)
    boxes = CollisionWorld(robot, [o.shapes[0] for o in result.obstacles])
    clearance = boxes.scene_clearances(q_goal[None], 1.0)[0]
    assert clearance >= CertificateConfig().guard_margin_m - 1e-9
    assert result.goal_valid_fraction == 1.0


def test_the_pocket_tier_closes_the_goals_pocket_first(box_heatmap):
    """``pocket_tier=1`` makes the joint goal's pocket the objective's first tier: the boxes
    cover at least as much of it as when it is weighed with the approaches (all of it but what
    one box cannot reach is the greedy's first aim), and the region form is left as it was."""
    from advocc_ros.attack import AttackConfig, attack
    from advocc_ros.attack.configurations import cover_matrix
    from advocc_ros.attack.region import search_region
    from advocc_ros.attack.task import TaskOptions
    from advocc_ros.kinematics.goal_batch import goal_pocket

    scene, robot, q_init = _problem('box')
    world = CollisionWorld(robot, scene.shapes)
    defaults = TaskOptions()
    pocket = goal_pocket(robot, world, scene.goal, defaults.pocket_samples, defaults.pocket_rad)
    region = search_region(box_heatmap, robot, scene.objects, q_init, scene.goal, AttackConfig())
    cover = cover_matrix(robot, world, pocket, region).tocsc()
    centers = region.center_m(np.argwhere(region.candidates))  # the cover's columns

    def covered(options):
        result = attack(box_heatmap, robot, scene.objects, q_init, scene.goal, 4, 'task',
                        AttackConfig(), certify=False, method_options=options)
        assert result.status.ok, result.message
        picks = [int(np.argmin(np.linalg.norm(centers - o.shapes[0].pose.position_m, axis=1)))
                 for o in result.obstacles]
        return int((cover[:, picks].sum(axis=1) > 0).sum()), result.stats

    plain, plain_stats = covered(TaskOptions())
    tiered, stats = covered(TaskOptions(pocket_tier=1))
    assert len(pocket) > 0 and stats['task_goal_samples'] == len(pocket)
    assert stats['task_goal_covered'] == tiered >= plain > 0
    assert stats['task_approach_samples'] == plain_stats['task_approach_samples'] - len(pocket)
    region_scene, _, _ = _problem('table_pick', 'region')
    boxes = [attack(box_heatmap, robot, region_scene.objects, q_init, region_scene.goal, 2,
                    'task', AttackConfig(), certify=False, method_options=options).obstacles
             for options in (TaskOptions(), TaskOptions(pocket_tier=1))]
    assert [o.shapes[0].pose.position_m for o in boxes[0]] == \
        [o.shapes[0].pose.position_m for o in boxes[1]]


def test_the_tube_tier_moves_the_witness_tube_into_the_goal_tier(box_heatmap):
    """``tube_tier=1``: the configurations around the kept witness leave the passage for the
    goal tier (weight 1 each, beside the pocket), so the boxes cover them as they close the
    goal in, and another placement results; the witness stays certified."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.attack.task import TaskOptions

    scene, robot, q_init = _problem('box')
    cfg = AttackConfig(goal_policy='solvable', victim_margin_m=0.004)
    results = [attack_task(box_heatmap, robot, scene.objects, q_init, scene.goal, 4, 'task', cfg,
                           method_options=TaskOptions(pocket_tier=1, tube_samples=1024,
                                                      tube_tier=tier))
               for tier in (0, 1)]
    for result in results:
        assert result.status.ok and result.solvable.verdict.value == 'certified', result.message
    plain, tiered = (r.stats for r in results)
    tube = plain['task_approach_samples'] - tiered['task_approach_samples']
    assert 0 < tube <= 1024  # the free ones of the tube's 1024 offsets
    assert tiered['task_goal_covered'] > plain['task_goal_covered']
    assert [o.shapes[0].pose.position_m for o in results[0].obstacles] != \
        [o.shapes[0].pose.position_m for o in results[1].obstacles]


def _without_and_with(heatmap, scene, robot, q_init, budget: int, **option):
    """The certified solvable attacks (joint form, pocket tier, the data set's victim margin)
    without and with the task option ``option`` (name=value)."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.attack.task import TaskOptions

    cfg = AttackConfig(goal_policy='solvable', victim_margin_m=0.004)
    results = [attack_task(heatmap, robot, scene.objects, q_init, scene.goal, budget, 'task', cfg,
                           method_options=TaskOptions(pocket_tier=1, **options))
               for options in ({}, option)]
    for result in results:
        assert result.status.ok and result.solvable.verdict.value == 'certified', result.message
    return results


def test_cut_routes_closes_the_other_candidate_witnesses(box_heatmap):
    """``cut_routes=1``: the witness search's other candidates are rays of the top tier, and
    the boxes block more of them than without (counted exactly, ``routes_cut``); the kept
    witness stays certified. ``route_rays`` holds every other candidate, its ends not. (One
    box on table_pick: without the routes it cuts none of them.)"""
    from advocc_ros.attack.edges import task_witness
    from advocc_ros.attack.exits import rays_cut, route_rays

    scene, robot, q_init = _problem('table_pick')
    witnesses = task_witness(robot, scene.objects, q_init, scene.goal, 0.004).witnesses
    assert len(witnesses) > 1
    rays = route_rays(robot, witnesses, witnesses[0])
    assert rays.count == len(witnesses) - 1
    q_goal = scene.goal.configuration(robot.joint_names)
    assert not np.isclose(rays.states, q_goal).all(axis=1).any()
    assert not np.isclose(rays.states, q_init).all(axis=1).any()
    assert route_rays(robot, witnesses[:1], witnesses[0]) is None
    plain, cutting = _without_and_with(box_heatmap, scene, robot, q_init, 1, cut_routes=1)
    assert 'routes' not in plain.stats and cutting.stats['routes'] == len(witnesses) - 1
    assert cutting.stats['routes_cut'] > rays_cut(
        robot, route_rays(robot, witnesses, plain.witness), plain.obstacles)
    assert rays_cut(robot, route_rays(robot, witnesses, cutting.witness), ()) == 0


def test_corridor_routes_are_free_paths_beside_the_witness_and_the_boxes_cut_them(box_heatmap):
    """``corridor_routes``: paths shifted from the kept witness (none at the start and the goal),
    those free on the scene rays of the top tier; zero offsets give the witness itself, offsets
    past the joint limits none; the boxes cut more of them than a placement without them."""
    from advocc_ros.attack.exits import corridor_rays, rays_cut
    from advocc_ros.attack.task import TaskOptions, task_sample
    from advocc_ros.attack.types import Task
    from advocc_ros.planning.witness import witness_states

    scene, robot, q_init = _problem('box')
    world = CollisionWorld(robot, scene.shapes)
    plain, cutting = _without_and_with(box_heatmap, scene, robot, q_init, 4, corridor_routes=256)
    Q = cutting.witness.configurations(robot)
    same = corridor_rays(world, Q, np.zeros((3, robot.nq)))
    assert same.count == 3
    np.testing.assert_allclose(same.states[same.ray == 0], witness_states(Q, 0.05)[1:-1])
    assert corridor_rays(world, Q, np.full((2, robot.nq), 10.0)) is None
    offsets = task_sample(Task(robot, scene.objects, q_init, scene.goal, 'solvable'),
                          TaskOptions(corridor_routes=256), 0).corridor_noise
    rays = corridor_rays(world, Q, offsets)
    assert 0 < rays.count < 256 and cutting.stats['corridor_routes'] == rays.count
    assert not world.collisions_batch(rays.states).any()
    assert 'corridor_routes' not in plain.stats
    assert cutting.stats['corridor_routes_cut'] > rays_cut(robot, rays, plain.obstacles)
    assert rays_cut(robot, rays, ()) == 0


def test_a_larger_pocket_sample_holds_the_smaller_and_stays_around_the_goal():
    """``pocket_samples`` draws more of the same stream (seed ``POCKET_SEED``): the smaller
    pocket's configurations are the larger's first ones, every one is free, within the limits
    and near the goal, and more of them are drawn at a larger ``pocket_rad``."""
    from advocc_ros.kinematics.goal_batch import goal_pocket

    scene, robot, _ = _problem('bookshelf_small')
    world = CollisionWorld(robot, scene.shapes)
    q_goal = scene.goal.configuration(robot.joint_names)
    small = goal_pocket(robot, world, scene.goal, 256, 0.2)
    large = goal_pocket(robot, world, scene.goal, 4096, 0.2)
    assert 0 < len(small) < len(large) <= 4096
    np.testing.assert_array_equal(large[:len(small)], small)
    assert not world.collisions_batch(large).any()
    assert np.all((large >= robot.lower) & (large <= robot.upper))
    spread = np.abs(large - q_goal)
    assert spread.max() < 0.2 * 6 and np.median(spread) < 0.2
    assert np.median(np.abs(goal_pocket(robot, world, scene.goal, 4096, 0.4) - q_goal)) > \
        np.median(spread)
    assert len(goal_pocket(robot, world, scene.goal, 0, 0.2)) == 0


def test_goal_rays_are_rrt_steps_from_the_goal_and_free_ones_are_checked_outwards():
    """``goal_ray_ends``: the same steps each time, each an RRT step (OMPL's default range) or
    shorter towards a state within the limits; ``free_rays`` agrees with checking every state
    of each motion, and a box around the hand closes them all."""
    from advocc_ros.kinematics.goal_batch import (RAY_RANGE_FRACTION, RAY_STEP_RAD, free_rays,
                                                  goal_ray_ends)

    scene, robot, _ = _problem('box')
    world = CollisionWorld(robot, scene.shapes)
    q_goal = scene.goal.configuration(robot.joint_names)
    ends = goal_ray_ends(robot, q_goal, 400)
    np.testing.assert_array_equal(ends, goal_ray_ends(robot, q_goal, 400))
    reach = np.linalg.norm(ends - q_goal, axis=1)
    assert reach.max() <= RAY_RANGE_FRACTION * np.linalg.norm(robot.upper - robot.lower) + 1e-9
    assert np.all((ends >= robot.lower - 1e-9) & (ends <= robot.upper + 1e-9))
    free = free_rays(world, q_goal, ends)
    brute = []
    for end in ends:
        n = max(int(np.ceil(np.linalg.norm(end - q_goal) / RAY_STEP_RAD)), 1)
        brute.append(world.first_collision(q_goal + np.arange(1, n + 1)[:, None] / n
                                           * (end - q_goal)) < 0)
    np.testing.assert_array_equal(free, brute)
    assert 0 < free.sum() < len(ends)  # the box the hand reaches into closes most, not all
    boxed = CollisionWorld(robot, list(scene.shapes) + list(
        make_box('cage', scene.goal.center.position_m, (0.3, 0.3, 0.3)).shapes))
    assert not free_rays(boxed, q_goal, ends).any()
    from advocc_ros.attack.exits import escape_share  # the same steps, independent rays

    open_ = escape_share(robot, scene.shapes, q_goal, 400, RAY_STEP_RAD)
    assert open_['rays'] == 400 and 0 < open_['free'] < 400
    assert not np.array_equal(goal_ray_ends(robot, q_goal, 400, 1000), ends)
    assert escape_share(robot, boxed.shapes, q_goal, 400, RAY_STEP_RAD)['free'] == 0


def test_exit_rays_keeps_the_witness_whose_boxes_leave_the_goal_fewest_exits(box_heatmap):
    """``exit_rays``: the boxes are placed for every candidate witness that keeps the margin,
    and the placement kept is the one with the fewest free goal rays, a count the attack's
    boxes reproduce; the witness it keeps is certified with them."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.attack.exits import GoalExits
    from advocc_ros.attack.task import TaskOptions
    from advocc_ros.attack.types import Task

    scene, robot, q_init = _problem('box')
    cfg = AttackConfig(goal_policy='solvable', victim_margin_m=0.004)
    result = attack_task(box_heatmap, robot, scene.objects, q_init, scene.goal, 4, 'task', cfg,
                         method_options=TaskOptions(pocket_tier=1, exit_rays=4096))
    assert result.status.ok, result.message
    stats = result.stats
    tried = stats['witness_exits']
    assert len(tried) > 1 and stats['goal_exit_rays'] == 4096
    assert stats['goal_exits'] == min(tried.values()) == tried[stats['witness_kept']]
    assert stats['witness_kept_for_exits'] == stats['witness_kept']
    clearance = stats['witness_scene_clearance_m']  # every candidate measured, capped at 4 mm
    assert len(clearance) >= len(tried) and clearance[stats['witness_kept']] >= 0.004 - 1e-9
    task = Task(robot, scene.objects, q_init, scene.goal, 'solvable')
    exits = GoalExits(task, 4096)
    assert len(exits.ends) == stats['goal_exits_unattacked'] > stats['goal_exits']
    assert exits.left_free(result.obstacles) == stats['goal_exits']
    assert result.solvable.verdict.value == 'certified'
    plain = attack_task(box_heatmap, robot, scene.objects, q_init, scene.goal, 4, 'task', cfg,
                        method_options=TaskOptions(pocket_tier=1))
    assert 'witness_exits' not in plain.stats
    assert exits.left_free(plain.obstacles) >= stats['goal_exits']
    fresh = GoalExits(task, 4096)
    assert fresh.left_free((), 1) > 0 and not np.array_equal(
        fresh.free_ends((), 1)[:8], fresh.ends[:8])  # a fresh draw is other rays
    # exit_rounds, the kept witness alone (one box leaves exits): its exits are counted and
    # closed too; each round is a fresh draw, and the kept placement's count on the draws it
    # was counted on is what its boxes leave free on them. The data set's record of a lone
    # candidate names its scene clearance.
    from advocc_ros.attack.api import attack
    from advocc_ros.dataset.job import _attack_entry

    lone = attack(box_heatmap, robot, scene.objects, q_init, scene.goal, 1, 'task', cfg,
                  method_options=TaskOptions(pocket_tier=1, exit_rays=4096, exit_rounds=2),
                  witness=result.witness)
    stats = lone.stats
    rounds, draws = stats['goal_exits_by_round'], stats['goal_exit_draws_kept']
    assert stats['witness_exits'] == {0: rounds[0]} and len(rounds) == 3
    assert stats['goal_exits'] == sum(rounds[d] for d in draws) == sum(
        exits.left_free(lone.obstacles, d) for d in draws)
    assert lone.solvable.verdict.value == 'certified'
    entry, attacked = _attack_entry(lone, scene, robot, q_init, 1.0)
    assert attacked is not None and entry['witness_scene_clearance_m'] >= 0.004 - 1e-9


DIRECT = pathlib.Path(__file__).parent / 'data' / 'mbm_direct_motion' / 'table_pick_panda'


def test_where_the_hand_hardly_moves_the_direct_motions_cube_goes_on_another_joint():
    """On bookshelf_small 0034 the direct motion turns the arm 3.9 rad while the hand moves a
    few cm: a cube on the hand touches the robot at the start or at the goal wherever it is put,
    so it goes on a joint that moves (the first of the joints' origins, last joint first)."""
    from advocc_ros.planning.direct_motion import (DIRECT_BLOCK_GOAL_M, DIRECT_BLOCK_START_M,
                                                   direct_blocker, direct_motion_free)
    from advocc_ros.planning.witness import WITNESS_STEP_RAD as STEP

    folder = DIRECT.parent / 'bookshelf_small_panda'
    scene = load_any_scene(folder / 'scene0034.yaml', folder / 'request0034.yaml')
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    q_goal = scene.goal.configuration(robot.joint_names)
    blocker = direct_blocker(robot, CollisionWorld(robot, scene.shapes), q_init, scene.goal,
                             STEP)
    cube = CollisionWorld(robot, list(blocker.shapes))
    assert not direct_motion_free(cube, q_init, q_goal, STEP)
    near = cube.scene_clearances(np.stack([q_init, q_goal]), 1.0)
    assert near[0] >= DIRECT_BLOCK_START_M and near[1] >= DIRECT_BLOCK_GOAL_M
    hand = robot.ee_pose(0.5 * (q_init + q_goal), link=scene.goal.link).translation
    assert np.abs(np.array(blocker.shapes[0].pose.position_m) - hand).max() > 0.05


def test_a_free_direct_motion_is_left_by_the_witness_and_cut_by_the_boxes(box_heatmap):
    """On table_pick 0033 the straight motion from the start to the joint goal is free. A
    witness on it would keep it open (no box may touch the witness) to every planner that tries
    the direct connection first; the search plans around a cube on it instead, and the motion
    is the objective's first row: the boxes cut it and the witness stays certified. Where the
    scene blocks the motion (box 0001) there is no cube and no such row."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.attack.task import TaskOptions
    from advocc_ros.planning.direct_motion import direct_blocker, direct_motion_free
    from advocc_ros.planning.witness import (WITNESS_STEP_RAD as STEP, grown_objects,
                                             search_witnesses, witness_states)

    scene = load_any_scene(DIRECT / 'scene0033.yaml', DIRECT / 'request0033.yaml')
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    q_goal = scene.goal.configuration(robot.joint_names)
    world = CollisionWorld(robot, scene.shapes)
    assert direct_motion_free(world, q_init, q_goal, STEP)
    blocker = direct_blocker(robot, world, q_init, scene.goal, STEP)
    cube = CollisionWorld(robot, list(blocker.shapes))
    assert not direct_motion_free(cube, q_init, q_goal, STEP)
    plain = search_witnesses(robot, world, scene.objects, q_init, scene.goal,
                             planned_among=grown_objects(scene.objects, 0.004))
    assert len(plain[0].waypoints) == 2  # without the cube: the straight motion itself
    cfg = AttackConfig(goal_policy='solvable', victim_margin_m=0.004)
    result = attack_task(box_heatmap, robot, scene.objects, q_init, scene.goal, 4, 'task', cfg,
                         method_options=TaskOptions(pocket_tier=1))
    assert result.status.ok, result.message
    assert result.stats['direct_motion'] == 'free' and result.stats['direct_motion_cut']
    assert result.solvable.verdict.value == 'certified'
    path = witness_states(result.witness.configurations(robot))
    assert not cube.collisions_batch(path).any()
    assert result.witness.source['direct_blocker_center_m'] == \
        list(blocker.shapes[0].pose.position_m)
    boxes = CollisionWorld(robot, [o.shapes[0] for o in result.obstacles])
    assert not direct_motion_free(boxes, q_init, q_goal, STEP)
    box, robot, q_init = _problem('box')
    q_goal = box.goal.configuration(robot.joint_names)
    blocked = CollisionWorld(robot, box.shapes)
    assert not direct_motion_free(blocked, q_init, q_goal, STEP)
    assert direct_blocker(robot, blocked, q_init, box.goal, STEP) is None
    result = attack_task(box_heatmap, robot, box.objects, q_init, box.goal, 2, 'task', cfg,
                         method_options=TaskOptions(pocket_tier=1))
    assert result.stats['direct_motion'] == 'blocked' and 'direct_motion_cut' not in result.stats


def test_only_the_region_form_keeps_boxes_off_the_goal_region(box_heatmap):
    """The region form's C3 keeps d_safe (10 cm) from the goal region's position box; the joint
    form keeps the goal's body clear instead, so boxes may close in around the hand."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.region import search_region

    cfg = AttackConfig()
    near = {}
    for form in ('joint', 'region'):
        scene, robot, q_init = _problem('table_pick', form)
        region = search_region(box_heatmap, robot, scene.objects, q_init, scene.goal, cfg)
        centers = region.center_m(np.argwhere(region.candidates))
        hand = np.array(scene.goal.center.position_m)
        near[form] = int((np.linalg.norm(centers - hand, axis=1) < 0.1).sum())
    assert near['region'] == 0 and near['joint'] > 0


def test_the_goal_form_travels_in_the_ros_message():
    """The heatmap server's ~/attack and the attacker node read the goal from a GoalRegion
    message: a joint goal keeps its form and configuration through it."""
    from advocc_ros.ros.conversions import goal_region_from_msg, goal_region_to_msg

    for form in ('joint', 'region'):
        scene, robot, _ = _problem('box', form)
        msg = goal_region_to_msg(scene.goal, 'panda_link0')
        assert msg.form == form
        back = goal_region_from_msg(msg, robot.spec.ee_link)
        assert back.form == form
        if form == 'joint':
            assert np.array_equal(back.configuration(robot.joint_names),
                                  scene.goal.configuration(robot.joint_names))
    msg = goal_region_to_msg(_problem('box')[0].goal, 'panda_link0')
    msg.joint_goal.position = []
    with pytest.raises(SceneError, match='one position per named joint'):
        goal_region_from_msg(msg, 'panda_hand')


def test_a_missing_witness_is_explained_in_the_goal_form_of_the_task():
    """The refusal of a ``solvable`` attack without a witness names the goal as posed: one
    configuration in the joint form, the region otherwise."""
    from advocc_ros.attack.edges import no_witness_message

    joint, region = no_witness_message('joint'), no_witness_message('region')
    assert 'no path to the goal configuration' in joint and 'region' not in joint
    assert 'no path into the goal region' in region and 'configuration' not in region
