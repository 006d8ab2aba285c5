"""Real-format MotionBenchMaker problems (test/data/mbm/families, see its README): the request's
own start and goal are valid once the fingers are locked at the task's robot state."""

import json
import pathlib

import numpy as np
import pytest

from advocc_ros.cli import main as cli_main
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.mbm import load_mbm_scene, load_request
from advocc_ros.model.robot import RobotSpec, load_robot

FAMILIES = pathlib.Path(__file__).resolve().parent / 'data' / 'mbm' / 'families'
PROBLEMS = sorted(FAMILIES.glob('*/scene*.yaml'))


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
