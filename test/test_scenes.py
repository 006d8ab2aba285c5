"""Shipped scenes, MotionBenchMaker import, shared scene arguments and the variation generator."""

import argparse
import dataclasses
import pathlib

import numpy as np
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.commands.common import add_scene_args, scene_from_args
from advocc_ros.formats.mbm_scene import (GoalTolerance, is_mbm_scene, load_any_scene,
                                          load_mbm_scene, parse_goal_tolerance)
from advocc_ros.kinematics.ik import GoalSampler, start_configuration
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import Scene, load_scene, make_box, read_yaml
from advocc_ros.scenes.variations import VariationConfig, vary_scene

REPO = pathlib.Path(__file__).resolve().parents[1]
MBM = REPO / 'test' / 'data' / 'mbm'
SCENES = ('table_pick', 'table_under_pick', 'bookshelf', 'box', 'cage')
READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
Q_GOAL = [0.3, 0.3, 0.0, -2.0, 0.0, 2.3, 0.785]  # request0001.yaml's goal


def _valid_goal_configs(robot, world, goal, attempts, seed=0):
    sampler = GoalSampler(robot, world.in_collision, goal, np.random.default_rng(seed))
    return [q for q in (sampler.attempt() for _ in range(attempts)) if q is not None]


@pytest.mark.parametrize('name', SCENES)
def test_shipped_scene_has_valid_start_and_reachable_goal_region(panda, name):
    scene = load_scene(REPO / 'config' / 'scenes' / f'{name}.yaml')
    assert scene.name == name and len(scene.objects) >= 8
    assert min(scene.goal.position_tolerance_m) > 0
    assert min(scene.goal.orientation_tolerance_rad) > 0
    world = CollisionWorld(panda, scene.shapes)
    q_init = start_configuration(scene, panda)
    assert world.is_valid(q_init)
    assert world.scene_distance(q_init) > 0.03
    goals = _valid_goal_configs(panda, world, scene.goal, 150)
    assert len(goals) >= 3, f'{name}: only {len(goals)} valid IK solutions in 150 attempts'
    for q in goals[:3]:
        assert world.is_valid(q) and scene.goal.contains(panda.ee_pose(q))


# ---------------------------------------------------------------------------------------------
# MotionBenchMaker import

def _shape(scene, obj_id, k=0):
    return next(o for o in scene.objects if o.id == obj_id).shapes[k]


def test_mbm_scene_objects_poses_and_start(panda):
    scene = load_mbm_scene(MBM / 'scene0001.yaml')
    assert scene.name == 'scene0001' and scene.frame == 'panda_link0'
    assert [o.id for o in scene.objects] == ['table', 'can', 'shelf', 'ball']
    table = _shape(scene, 'table')
    assert table.kind == 'box' and table.dims == pytest.approx((0.6, 1.0, 0.1))
    assert table.pose.position_m == pytest.approx((0.6, 0.0, 0.05))
    # cylinder dimensions are [height, radius]; rotated 90 deg about x its axis is the base y
    can = _shape(scene, 'can')
    assert can.kind == 'cylinder' and can.dims == pytest.approx((0.12, 0.03))
    lo, hi = can.trimesh().bounds
    np.testing.assert_allclose(hi - lo, [0.06, 0.12, 0.06], atol=1e-3)
    np.testing.assert_allclose((hi + lo) / 2, [0.5, 0.2, 0.13], atol=1e-6)
    # the object pose (yaw 90 deg at (0.7, -0.3, 0.3)) composes with the primitive poses
    shelf = next(o for o in scene.objects if o.id == 'shelf')
    assert len(shelf.shapes) == 2
    np.testing.assert_allclose(shelf.shapes[0].pose.position_m, [0.7, -0.2, 0.3], atol=1e-9)
    np.testing.assert_allclose(shelf.shapes[1].pose.position_m, [0.7, -0.4, 0.3], atol=1e-9)
    lo, hi = shelf.shapes[0].trimesh().bounds
    np.testing.assert_allclose(hi - lo, [0.3, 0.02, 0.4], atol=1e-9)
    ball = _shape(scene, 'ball')
    assert ball.kind == 'sphere' and ball.dims == pytest.approx((0.04,))
    # start from robot_state, fingers included: they lock the fingers (docs/design.md)
    assert [scene.start[j] for j in panda.joint_names] == pytest.approx(READY)
    assert scene.start['panda_finger_joint1'] == pytest.approx(0.035)
    assert dict(scene.robot.locked) == pytest.approx({'panda_finger_joint1': 0.035,
                                                      'panda_finger_joint2': 0.035})
    assert scene.goal is None
    robot = load_robot(scene.robot)
    assert robot.locked_values == pytest.approx({'panda_finger_joint1': 0.035,
                                                 'panda_finger_joint2': 0.035})
    assert robot.hash != panda.hash  # open fingers: another robot for heatmaps
    assert CollisionWorld(robot, scene.shapes).is_valid(np.array(READY))


def test_mbm_request_gives_start_and_goal_region_at_fk_of_goal_joints(panda):
    tol = GoalTolerance((0.01, 0.02, 0.03), (0.1, 0.2, 0.3))
    scene = load_mbm_scene(MBM / 'scene0001.yaml', MBM / 'request0001.yaml', tol)
    assert [scene.start[j] for j in panda.joint_names] == pytest.approx(
        [0.1, -0.7, 0.0, -2.3, 0.0, 1.6, 0.785])
    T = panda.ee_pose(np.array(Q_GOAL))
    centre = scene.goal.center.to_se3()
    np.testing.assert_allclose(centre.translation, T.translation, atol=1e-9)
    np.testing.assert_allclose(centre.rotation, T.rotation, atol=1e-9)
    assert scene.goal.position_tolerance_m == (0.01, 0.02, 0.03)
    assert scene.goal.orientation_tolerance_rad == (0.1, 0.2, 0.3)
    assert scene.goal.link == 'panda_hand'
    world = CollisionWorld(panda, scene.shapes)
    assert world.is_valid(np.array(Q_GOAL))  # the request's goal itself is a valid solution
    assert _valid_goal_configs(panda, world, scene.goal, 50)


@pytest.mark.parametrize('scene_file, request_file, match', [
    ('scene_bad_cylinder.yaml', None,
     r'scene_bad_cylinder.yaml: world.collision_objects\[1\].primitives\[0\].dimensions: '
     r'a cylinder needs \[height, radius\]'),
    ('scene_bad_type.yaml', None,
     r'scene_bad_type.yaml: world.collision_objects\[3\].primitives\[0\].type: .*cone'),
    ('scene_bad_frame.yaml', None,
     r'scene_bad_frame.yaml: world.collision_objects\[1\].header.frame_id: .camera_link.'),
    ('scene0001.yaml', 'request_no_goal.yaml', r'request_no_goal.yaml: goal_constraints: missing'),
    ('scene0001.yaml', 'request_missing_joint.yaml',
     r'request_missing_joint.yaml: goal_constraints\[0\].joint_constraints: missing joints '
     r"\['panda_joint7'\]"),
])
def test_malformed_mbm_files_name_file_and_field(scene_file, request_file, match):
    with pytest.raises(SceneError, match=match):
        load_mbm_scene(MBM / scene_file, MBM / request_file if request_file else None)


@pytest.mark.parametrize('edit, match', [
    (lambda d: d['world']['collision_objects'][0]['primitive_poses'][0].update(
        orientation=[0, 0, 1]), r'collision_objects\[0\].primitive_poses\[0\].orientation: '
     r'expected 4 numbers'),
    (lambda d: d['world']['collision_objects'][0]['primitive_poses'].append(
        {'position': [0, 0, 0]}), r'collision_objects\[0\].primitive_poses: 2 poses for 1'),
    (lambda d: d['world']['collision_objects'][1].update(id='table'),
     r"collision_objects\[1\].id: duplicate id 'table'"),
    (lambda d: d['world']['collision_objects'][2]['pose']['position'].pop('z'),
     r"collision_objects\[2\].pose.position: missing \['z'\]"),
    (lambda d: d['world']['collision_objects'][3]['primitives'][0].update(dimensions=[-1]),
     r'collision_objects\[3\].primitives\[0\].dimensions: values must be > 0'),
    (lambda d: d['robot_state']['joint_state'].update(position=[0.0] * 3),
     r'robot_state.joint_state: 9 names but 3 positions'),
    (lambda d: d.update(world=[1, 2]), r'world: expected a mapping'),
])
def test_malformed_mbm_scene_variants(tmp_path, edit, match):
    import yaml
    data = read_yaml(MBM / 'scene0001.yaml')
    edit(data)
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError, match=match) as info:
        load_mbm_scene(path)
    assert str(path) in str(info.value)


def test_malformed_mbm_request_variants(tmp_path):
    import yaml
    cases = [
        (lambda d: d['goal_constraints'][0]['joint_constraints'][2].pop('position'),
         r'goal_constraints\[0\].joint_constraints\[2\].position: missing'),
        (lambda d: d['goal_constraints'][0]['joint_constraints'][0].update(position='x'),
         r'goal_constraints\[0\].joint_constraints\[0\].position: expected numbers'),
        (lambda d: d['goal_constraints'][0].update(joint_constraints=[]),
         r'goal_constraints\[0\].joint_constraints: missing or empty'),
        (lambda d: d['start_state']['joint_state'].update(name='panda_joint1'),
         r'start_state.joint_state.name: expected a list'),
    ]
    for k, (edit, match) in enumerate(cases):
        data = read_yaml(MBM / 'request0001.yaml')
        edit(data)
        path = tmp_path / f'request{k}.yaml'
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(SceneError, match=match) as info:
            load_mbm_scene(MBM / 'scene0001.yaml', path)
        assert str(path) in str(info.value)


def test_goal_tolerance_parsing():
    assert parse_goal_tolerance('pos=0.01,0.02,0.03;rot=0.2') == GoalTolerance(
        (0.01, 0.02, 0.03), (0.2, 0.2, 0.2))
    assert parse_goal_tolerance('rot=0.3') == GoalTolerance((0.02,) * 3, (0.3,) * 3)
    for bad in ('pos=a', 'size=1', 'pos=1,2', 'rot=-0.1', 'pos=nan'):
        with pytest.raises(SceneError, match='--goal-tol'):
            parse_goal_tolerance(bad)


def test_scene_args_accept_names_our_files_and_mbm_files():
    parser = argparse.ArgumentParser()
    add_scene_args(parser)
    args = parser.parse_args(['--scene', 'box'])
    assert scene_from_args(args).name == 'box'
    # --goal-tol alone replaces the given tolerances of the scene's own goal region
    args = parser.parse_args(['--scene', 'table_pick', '--goal-tol', 'rot=0.05'])
    goal = scene_from_args(args).goal
    assert goal.position_tolerance_m == (0.03, 0.03, 0.02)
    assert goal.orientation_tolerance_rad == (0.05, 0.05, 0.05)
    args = parser.parse_args(['--scene', str(MBM / 'scene0001.yaml'), '--request',
                              str(MBM / 'request0001.yaml'), '--goal-tol', 'pos=0.05'])
    scene = scene_from_args(args)
    assert scene.name == 'scene0001' and scene.goal.position_tolerance_m == (0.05,) * 3
    assert is_mbm_scene(read_yaml(MBM / 'scene0001.yaml'))
    assert not is_mbm_scene(read_yaml(REPO / 'config' / 'scenes' / 'box.yaml'))
    # a request on one of our scenes replaces its start and goal
    scene = load_any_scene('box', MBM / 'request0001.yaml')
    assert scene.start['panda_joint1'] == pytest.approx(0.1) and len(scene.objects) == 12
    with pytest.raises(SceneError, match='no goal region'):
        load_any_scene(MBM / 'scene0001.yaml', goal_tol='pos=0.01')


# ---------------------------------------------------------------------------------------------
# Variations

def test_variations_are_deterministic_valid_and_keep_structure(panda):
    scene = load_scene(REPO / 'config' / 'scenes' / 'bookshelf.yaml')
    a = [vary_scene(scene, i, seed=7) for i in range(2)]
    b = vary_scene(scene, 1, seed=7)
    assert a[1].scene.to_data() == b.scene.to_data()
    assert a[0].scene.to_data() != a[1].scene.to_data()
    assert vary_scene(scene, 0, seed=8).scene.to_data() != a[0].scene.to_data()
    base = {o.id: o.shapes[0] for o in scene.objects}
    for var in a:
        new = {o.id: o.shapes[0] for o in var.scene.objects}
        assert var.scene.name == f'bookshelf_{var.index:04d}'
        # the shelf moves as one body and keeps its size
        shifts = {k: np.subtract(new[k].pose.position_m, base[k].pose.position_m)
                  for k in base if k.startswith('shelf_')}
        first = next(iter(shifts.values()))
        assert np.linalg.norm(first) > 0
        for shift in shifts.values():
            np.testing.assert_allclose(shift, first, atol=1e-12)
        assert all(new[k].dims == base[k].dims for k in shifts)
        # items stay within the jitter; the target keeps its size and the goal follows it
        assert all(abs(d) <= 0.02 + 1e-9 for k in base for d in np.subtract(
            new[k].pose.position_m, base[k].pose.position_m)[:2])
        assert new['target_can'].dims == base['target_can'].dims
        rel_old = np.subtract(scene.goal.center.position_m, base['target_can'].pose.position_m)
        rel_new = np.subtract(var.scene.goal.center.position_m,
                              new['target_can'].pose.position_m)
        assert np.linalg.norm(rel_new) == pytest.approx(np.linalg.norm(rel_old))
        world = CollisionWorld(panda, var.scene.shapes)
        assert world.is_valid(start_configuration(var.scene, panda))
        assert _valid_goal_configs(panda, world, var.scene.goal, 150)


def test_objects_touching_the_start_pose_are_redrawn(panda):
    # a box 5 mm beside the Panda's hand at its ready pose: about half its draws touch the hand
    near = make_box('near_hand', [0.307, 0.13, 0.54], [0.04, 0.04, 0.04])
    goal = GoalRegion(Pose((0.5, -0.2, 0.3), (1.0, 0.0, 0.0, 0.0)))
    scene = Scene((near,), dict(zip(panda.joint_names, READY)), goal, name='near')
    config = VariationConfig(jitter_pos_m=0.03, jitter_size=0.0, jitter_yaw_rad=0.0)
    variations = [vary_scene(scene, i, 0, config) for i in range(6)]
    assert sum(v.redrawn_objects for v in variations) > 0
    bare = CollisionWorld(panda)
    for var in variations:
        assert not bare.shape_collides(var.scene.shapes[0], np.array(READY), 0.005)
    # a goal region inside an object can never be reached: a clear error after max_draws
    blocked = dataclasses.replace(scene, objects=(make_box('wall', [0.5, -0.2, 0.3],
                                                           [0.3, 0.3, 0.3]),))
    with pytest.raises(SceneError, match='no valid variation 0'):
        vary_scene(blocked, 0, 0, dataclasses.replace(config, max_draws=2, ik_attempts=20))


def test_scenes_vary_cli_writes_loadable_files(tmp_path):
    from advocc_ros.cli import main
    assert main(['scenes', 'vary', '--scene', 'box', '--count', '2', '--seed', '3', '--out',
                 str(tmp_path), '--jitter-pos', '0.01']) == 0
    files = sorted(tmp_path.glob('*.yaml'))
    assert [f.name for f in files] == ['box_0000.yaml', 'box_0001.yaml']
    written = load_scene(files[1])
    expected = vary_scene(load_scene(REPO / 'config' / 'scenes' / 'box.yaml'), 1, 3,
                          VariationConfig(jitter_pos_m=0.01)).scene
    assert written.goal.center.position_m == pytest.approx(expected.goal.center.position_m)
    for got, want in zip(written.shapes, expected.shapes, strict=True):
        assert got.kind == want.kind and got.dims == pytest.approx(want.dims)
        assert got.pose.position_m == pytest.approx(want.pose.position_m)
        assert got.pose.quat_xyzw == pytest.approx(want.pose.quat_xyzw)
    assert not list(tmp_path.glob('.*.tmp'))
    assert main(['scenes', 'vary', '--scene', 'box', '--count', '1', '--out', str(tmp_path),
                 '--jitter-size', '1.5']) == 2


def test_scenes_convert_check_and_list_cli(tmp_path, capsys):
    from advocc_ros.cli import main
    out = tmp_path / 'converted.yaml'
    assert main(['scenes', 'convert', '--scene', str(MBM / 'scene0001.yaml'), '--request',
                 str(MBM / 'request0001.yaml'), '--out', str(out)]) == 0
    original = load_mbm_scene(MBM / 'scene0001.yaml', MBM / 'request0001.yaml')
    converted = load_scene(out)
    assert len(converted.shapes) == len(original.shapes) == 5
    assert converted.goal.center.position_m == pytest.approx(original.goal.center.position_m)
    assert main(['scenes', 'check', '--scene', str(out), '--ik-attempts', '30']) == 0
    capsys.readouterr()
    assert main(['scenes', 'list']) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in SCENES)
    assert main(['scenes', 'check', '--scene', str(MBM / 'scene_bad_type.yaml')]) == 2
