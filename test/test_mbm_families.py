"""Real-format MotionBenchMaker problems (test/data/mbm/families, see its README): the request's
own start and goal are valid once the fingers are locked at the task's robot state."""

import json
import pathlib

import numpy as np
import pytest

from advocc_ros.cli import main as cli_main
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.formats.mbm_scene import load_mbm_scene, load_request
from advocc_ros.model.robot import RobotSpec, load_robot

FAMILIES = pathlib.Path(__file__).resolve().parent / 'data' / 'mbm' / 'families'
PROBLEMS = sorted(FAMILIES.glob('*/scene*.yaml'))
DATA = FAMILIES.parent


def test_every_family_is_there():
    assert {p.parent.name for p in PROBLEMS} == {
        'table_pick', 'table_under_pick', 'box', 'cage', 'bookshelf_small', 'bookshelf_tall',
        'bookshelf_thin'}


@pytest.mark.parametrize('scene_file', PROBLEMS, ids=lambda p: f'{p.parent.name}/{p.stem}')
def test_request_goal_is_valid_with_the_task_fingers(scene_file):
    request_file = scene_file.with_name(scene_file.name.replace('scene', 'request'))
    scene = load_mbm_scene(scene_file, request_file)
    robot = load_robot(scene.robot)
    # 0.065 in the file, clipped to the URDF's 0.04; finger 2 mimics finger 1
    assert robot.locked_values == pytest.approx({'panda_finger_joint1': 0.04,
                                                 'panda_finger_joint2': 0.04})
    world = CollisionWorld(robot, scene.shapes)
    request = load_request(request_file, robot)
    q_start = np.array([request.start[j] for j in robot.joint_names])
    assert world.is_valid(q_start)
    if request.goal is not None:
        q_goal = np.array([request.goal[j] for j in robot.joint_names])
        assert world.is_valid(q_goal)
        assert scene.goal.contains(robot.ee_pose(q_goal))
        # the bug this guards against: with the SRDF's closed fingers the grasp collides
        closed = CollisionWorld(load_robot(RobotSpec()), scene.shapes)
        assert not closed.is_valid(q_goal)
    else:  # a pose goal: MoveIt's region, exact for a box oriented like the goal
        assert scene.goal.position_tolerance_m == pytest.approx((0.005,) * 3)
        assert scene.goal.orientation_tolerance_rad == pytest.approx((0.01,) * 3)
        assert scene.goal.tool_offset.position_m == pytest.approx((0, 0, 0.1034))


def test_scenes_check_reports_request_validity(capsys):
    scene = FAMILIES / 'table_pick' / 'scene0001.yaml'
    code = cli_main(['scenes', 'check', '--scene', str(scene), '--request',
                     str(scene.with_name('request0001.yaml')), '--ik-attempts', '20', '--json'])
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    assert report['request_goal_valid'] is True and report['request_start_valid'] is True
    assert report['locked_joints'] == pytest.approx({'panda_finger_joint1': 0.04,
                                                     'panda_finger_joint2': 0.04})


def _pose_request(tmp_path, primitive, region_q, goal_q=(1.0, 0.0, 0.0, 0.0)):
    import yaml

    data = yaml.safe_load((DATA / 'request0001.yaml').read_text())
    data['goal_constraints'] = [{
        'position_constraints': [{
            'header': {'frame_id': 'panda_link0'}, 'link_name': 'panda_hand',
            'constraint_region': {'primitives': [primitive], 'primitive_poses': [
                {'position': [0.5, 0.1, 0.4], 'orientation': [float(v) for v in region_q]}]}}],
        'orientation_constraints': [{
            'header': {'frame_id': 'panda_link0'}, 'link_name': 'panda_hand',
            'orientation': list(goal_q), 'absolute_x_axis_tolerance': 0.1,
            'absolute_y_axis_tolerance': 0.1, 'absolute_z_axis_tolerance': 0.3}]}]
    path = tmp_path / 'request.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def _inside(kind, dims, p_local):
    if kind == 'box':
        return np.all(np.abs(p_local) <= np.asarray(dims) / 2 + 1e-12)
    if kind == 'sphere':
        return np.linalg.norm(p_local) <= dims[0] + 1e-12
    return (abs(p_local[2]) <= dims[0] / 2 + 1e-12
            and np.linalg.norm(p_local[:2]) <= dims[1] + 1e-12)


@pytest.mark.parametrize('kind,dims,region_q,half', [
    ('box', [0.10, 0.06, 0.04], (1.0, 0.0, 0.0, 0.0), (0.05, 0.03, 0.02)),  # aligned: exact
    ('sphere', [0.03], (0.0, 0.0, 0.0, 1.0), (0.03 / np.sqrt(3),) * 3),
    ('cylinder', [0.10, 0.02], (0.0, 0.0, 0.0, 1.0), (0.02 / np.sqrt(3),) * 3),
    ('cylinder', [0.03, 0.05], (0.0, 0.0, 0.0, 1.0), (0.015 / np.sqrt(3),) * 3),
    ('box', [0.10, 0.06, 0.04], (0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)),
     (0.02 / np.sqrt(3),) * 3),  # turned 45 deg away from the goal orientation
])
def test_pose_goal_region_half_extents_lie_inside_the_constraint_region(
        tmp_path, panda, kind, dims, region_q, half):
    """A MoveIt constraint region becomes a goal box that never leaves it: exact for a box
    aligned with the goal orientation, the cube inside the inscribed sphere otherwise."""
    import itertools

    import pinocchio as pin

    types = {'box': 1, 'sphere': 2, 'cylinder': 3}
    path = _pose_request(tmp_path, {'type': types[kind], 'dimensions': dims}, region_q)
    goal = load_request(path, panda).goal_region
    np.testing.assert_allclose(goal.position_tolerance_m, half, atol=1e-12)
    np.testing.assert_allclose(goal.center.position_m, [0.5, 0.1, 0.4])
    x, y, z, w = region_q
    R_region = pin.Quaternion(w, x, y, z).toRotationMatrix()
    T_goal = goal.center.to_se3()
    for signs in itertools.product((-1, 1), repeat=3):
        corner = T_goal.act(np.asarray(signs) * np.asarray(goal.position_tolerance_m))
        assert _inside(kind, dims, R_region.T @ (corner - np.array([0.5, 0.1, 0.4])))
