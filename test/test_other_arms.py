"""Other arms end to end: heatmap -> attack -> evaluate on the UR5 and xArm7 scenes.

Adding an attack method to these tests is one entry in ``METHODS``.
"""

import pathlib

import pytest

from advocc_ros.attack import attack
from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.kinematics.ik import start_configuration

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

REPO = pathlib.Path(__file__).resolve().parents[1]
ARMS = ('ur5_table', 'xarm7_table')
METHODS = ('task', 'ours', 'random')


@pytest.fixture(scope='module', params=ARMS)
def arm(request):
    scene = load_scene(REPO / 'config' / 'scenes' / f'{request.param}.yaml')
    robot = load_robot(scene.robot)
    heatmap = build_heatmap(scene, HeatmapConfig(samples=300), seed=1)
    return scene, robot, heatmap


def test_arm_scene_loads_with_its_own_robot(arm):
    scene, robot, heatmap = arm
    assert robot.nq == len(scene.start) and robot.spec.ee_link == scene.goal.link
    assert heatmap.meta['robot_hash'] == robot.hash
    assert float(heatmap.values.max()) > 0
    world = CollisionWorld(robot, scene.shapes)
    assert world.is_valid(start_configuration(scene, robot))


@pytest.mark.parametrize('method', METHODS)
def test_attack_then_evaluate(arm, method):
    scene, robot, heatmap = arm
    q_init = start_configuration(scene, robot)
    result = attack(heatmap, robot, scene.objects, q_init, scene.goal, 3, method, seed=2)
    assert result.status.name in ('SUCCESS', 'PARTIAL'), result.message
    assert 1 <= len(result.obstacles) <= 3
    attacked = scene.with_objects(result.obstacles)
    assert CollisionWorld(robot, attacked.shapes).is_valid(q_init)
    row = evaluate_planner(attacked, 'rrtconnect', trials=1, time_budget_s=2.0, seed=0)
    assert row['trials'] == 1 and len(row['records']) == 1
    # the task stays well-posed after the attack: the planner runs and ends normally (or finds
    # every goal pose it samples blocked: the task attack cuts the goal set first)
    assert row['records'][0]['status'] in ('SUCCESS', 'TIMED_OUT', 'PLANNING_FAILED',
                                           'GOAL_IN_COLLISION'), row
