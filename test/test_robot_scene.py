"""Robot model (Panda and a UR5 from example-robot-data) and scene files."""

import pathlib

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotError, RobotSpec, load_robot
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import (apply_operation, load_scene, make_box, objects_from_data,
                                    Operation)

UR5 = RobotSpec(urdf='example-robot-data://ur_description/urdf/ur5_robot.urdf',
                srdf='example-robot-data://ur_description/srdf/ur5.srdf', group='',
                ee_link='tool0')
READY = np.array([0, -0.785, 0, -2.356, 0, 1.571, 0.785])


def test_panda_is_reduced_to_its_seven_arm_joints(panda):
    assert panda.nq == 7
    assert panda.joint_names == tuple(f'panda_joint{i}' for i in range(1, 8))
    assert len(panda.self_pairs) > 20
    world = CollisionWorld(panda)
    assert world.is_valid(READY)
    # folding the arm onto itself collides (joint 4 at its limit with joint 2 forward)
    assert world.in_collision(np.array([0, 1.7, 0, -3.0, 0, 0.0, 0]))


def test_panda_kinematics(panda):
    T = panda.ee_pose(READY)
    np.testing.assert_allclose(T.translation, [0.307, 0.0, 0.59], atol=2e-3)
    J = panda.ee_jacobian(READY)
    assert J.shape == (6, 7)
    # finite-difference check of the linear part of the Jacobian
    eps = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = eps
        fd = (panda.ee_pose(READY + dq).translation - T.translation) / eps
        np.testing.assert_allclose(J[:3, j], fd, atol=1e-5)
    assert panda.manipulability(READY) == pytest.approx(np.sqrt(np.linalg.det(J @ J.T)))


def test_ur5_loads_from_example_robot_data():
    ur5 = load_robot(UR5)
    assert ur5.nq == 6
    world = CollisionWorld(ur5, [make_box('wall', [0.0, 0.0, -0.2], [2, 2, 0.1]).shapes[0]])
    q = np.array([0, -1.57, 1.2, -1.2, -1.57, 0])
    assert world.is_valid(q)
    assert 0 < world.scene_distance(q) < 2
    assert ur5.manipulability(q) > 0


def test_robot_errors_are_clear(tmp_path):
    with pytest.raises(RobotError, match='URDF not found'):
        load_robot(RobotSpec(urdf=str(tmp_path / 'nope.urdf')))
    with pytest.raises(RobotError, match='no group named'):
        load_robot(RobotSpec(group='legs'))
    with pytest.raises(RobotError, match='end-effector link'):
        load_robot(RobotSpec(ee_link='gripper_of_doom'))
    panda = load_robot()
    with pytest.raises(RobotError, match='missing joints'):
        panda.q_from_names(['panda_joint1'], [0.0])
    with pytest.raises(RobotError, match='non-finite'):
        panda.check_q([np.nan] * 7)


def test_table_scene_loads(table_scene, panda):
    assert table_scene.name == 'table_pick'
    assert len(table_scene.objects) == 10
    q = panda.q_from_names(list(table_scene.start), list(table_scene.start.values()))
    assert CollisionWorld(panda, table_scene.shapes).is_valid(q)
    assert table_scene.goal.contains(table_scene.goal.center.to_se3())


def test_goal_region_contains():
    goal = GoalRegion(Pose((0.5, 0.0, 0.4), (1.0, 0.0, 0.0, 0.0)), (0.02, 0.03, 0.01),
                      (0.1, 0.1, 0.5))
    T = goal.center.to_se3()
    # position: box half-extents in the centre frame (rotated 180 deg about x: z flips)
    inside = pin.SE3(T.rotation, T.translation + np.array([0.019, -0.029, 0.009]))
    outside = pin.SE3(T.rotation, T.translation + np.array([0.0, 0.0, 0.011]))
    assert goal.contains(inside) and not goal.contains(outside)
    yaw = pin.SE3(T.rotation @ pin.rpy.rpyToMatrix(0, 0, 0.4), T.translation)
    tilt = pin.SE3(T.rotation @ pin.rpy.rpyToMatrix(0.2, 0, 0), T.translation)
    assert goal.contains(yaw) and not goal.contains(tilt)


def _write(tmp_path, text):
    path = tmp_path / 'scene.yaml'
    path.write_text(text)
    return path


@pytest.mark.parametrize('text, field', [
    ('objects: [{id: a, type: box}]', r'objects\[0\].size'),
    ('objects: [{id: a, type: box, size: [1, 2]}]', r'objects\[0\].size'),
    ('objects: [{id: a, type: box, size: [1, .nan, 1]}]', r'objects\[0\].size'),
    ('objects: [{id: a, type: box, size: [1, -1, 1]}]', r'objects\[0\].size'),
    ('objects: [{id: a, type: cone, radius: 1}]', r'objects\[0\].type'),
    ('objects: [{id: a, type: sphere, radius: 1}, {id: a, type: sphere, radius: 1}]',
     r'objects\[1\].id'),
    ('objects: [{id: a, type: mesh, file: missing.stl}]', r'objects\[0\].file'),
    ('objects: [{id: a, type: sphere, radius: 1, pose: {position: [0, 0]}}]',
     r'objects\[0\].pose.position'),
    ('goal: {center: {position: [0, 0, 0]}, position_tolerance: [-1, 0, 0]}',
     'goal.position_tolerance'),
    ('goal: {position_tolerance: [1, 1, 1]}', 'goal.center'),
    ('start: {panda_joint1: abc}', 'start.panda_joint1'),
    ('objects: {a: 1}', 'objects'),
    ('unexpected: 1', 'unknown field'),
    ('objects: [{id: a, type: box, size: [1, 1, 1]', 'malformed YAML'),
    ('- just\n- a list', 'top level'),
])
def test_malformed_scene_names_file_and_field(tmp_path, text, field):
    path = _write(tmp_path, text)
    with pytest.raises(SceneError, match=field) as err:
        load_scene(path)
    assert str(path) in str(err.value)


def test_mesh_objects_from_stl_obj_ply(tmp_path):
    import trimesh
    mesh = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    for suffix in ('stl', 'obj', 'ply'):
        mesh.export(tmp_path / f'm.{suffix}')
    objs = objects_from_data([{'id': f'm_{s}', 'type': 'mesh', 'file': f'm.{s}'}
                              for s in ('stl', 'obj', 'ply')], 'objects', tmp_path)
    for obj in objs:
        assert obj.shapes[0].trimesh().volume == pytest.approx(0.006, rel=1e-6)


def test_collision_object_operations():
    objs = apply_operation({}, Operation.ADD, make_box('a', [0, 0, 0], [1, 1, 1]))
    objs = apply_operation(objs, Operation.APPEND, make_box('a', [2, 0, 0], [1, 1, 1]))
    assert len(objs['a'].shapes) == 2
    objs = apply_operation(objs, Operation.MOVE, objs['a'], Pose((0, 1, 0)))
    np.testing.assert_allclose(objs['a'].shapes[1].pose.position_m, [2, 1, 0])
    objs = apply_operation(objs, Operation.REMOVE, make_box('a', [0, 0, 0], [1, 1, 1]))
    assert objs == {}
    with pytest.raises(SceneError, match='no object'):
        apply_operation(objs, Operation.REMOVE, make_box('zz', [0, 0, 0], [1, 1, 1]))


def test_shipped_scene_files_load():
    scenes = sorted((pathlib.Path(__file__).parents[1] / 'config' / 'scenes').glob('*.yaml'))
    assert scenes
    for path in scenes:
        assert load_scene(path).goal is not None
