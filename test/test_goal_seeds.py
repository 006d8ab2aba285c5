"""A joint goal reaches the planner as the goal region's seed (MoveIt plans to it itself)."""

import dataclasses
import pathlib

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import (GoalSampler, goal_configuration, seed_configurations,
                                      start_configuration)
from advocc_ros.formats.mbm_scene import load_any_scene
from advocc_ros.model.robot import load_robot
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.scene import scene_from_data

import pytest

FAMILY = pathlib.Path(__file__).parent / 'data' / 'mbm' / 'families' / 'table_pick'


@pytest.fixture(scope='module')
def task():
    scene = load_any_scene(FAMILY / 'scene0001.yaml', FAMILY / 'request0001.yaml',
                           goal_form='region')  # a region whose seed is the request's goal
    return scene, load_robot(scene.robot)


def test_joint_goal_is_the_region_seed(task):
    scene, robot = task
    seeds = seed_configurations(robot, scene.goal)
    assert seeds.shape == (1, robot.nq)
    assert scene.goal.seed_joints == robot.joint_names
    T = robot.ee_pose(seeds[0])
    assert scene.goal.contains(T * scene.goal.tool_offset.to_se3())
    # the attack keeps the hand clear at the joint goal itself
    q = goal_configuration(robot, scene.goal, start_configuration(scene, robot))
    assert np.allclose(q, seeds[0])


def test_sampler_offers_the_seed_first_then_walks_near_it(task):
    scene, robot = task
    world = CollisionWorld(robot, scene.shapes)
    sampler = GoalSampler(robot, world.in_collision, scene.goal, np.random.default_rng(0))
    first = sampler.attempt()
    assert first is not None and np.allclose(first, sampler.seeds[0])
    goals = sampler.sample(6, float('inf'))
    assert len(goals) == 6 and all(sampler.region_distance(q) == 0.0 for q in goals)
    assert not any(world.in_collision(q) for q in goals)


def test_seeds_round_trip_through_our_scene_yaml(task):
    scene, _ = task
    data = scene.to_data()
    assert set(data['goal']['seeds'][0]) == set(scene.goal.seed_joints)
    assert scene_from_data(data, 'x').goal == scene.goal
    seedless = dataclasses.replace(scene.goal, seeds=(), seed_joints=())
    assert 'seeds' not in seedless.to_data()  # old files and goal hashes unchanged


def test_malformed_seeds_are_refused():
    goal = {'center': {'position': [0.5, 0, 0.5]}}
    with pytest.raises(SceneError, match='seeds'):
        GoalRegion.from_data(dict(goal, seeds=[{'a': 1.0}, {'b': 2.0}]))
    with pytest.raises(SceneError, match='seeds'):
        GoalRegion.from_data(dict(goal, seeds={'a': 1.0}))


def test_seeds_of_another_robot_are_ignored(task):
    scene, robot = task
    goal = dataclasses.replace(scene.goal, seed_joints=('elbow',), seeds=((0.1,),))
    assert seed_configurations(robot, goal).shape == (0, robot.nq)


@pytest.mark.processes
def test_the_planner_worker_reaches_a_joint_goal_through_its_seed(task):
    """With one DLS iteration per IK attempt, random-seed IK never lands in a 0.1 mm / 1 mrad
    region; the seed (already inside) and walks near it do, so the seed crossed the worker's
    process boundary. The seedless goal fails as NO_IK_SOLUTION."""
    from advocc_ros.planning.worker import Planner
    from advocc_ros.planning.types import PlanningConfig
    scene, robot = task
    tight = dataclasses.replace(scene.goal, position_tolerance_m=(1e-4,) * 3,
                                orientation_tolerance_rad=(1e-3,) * 3)
    q_start = start_configuration(scene, robot)
    with Planner(scene.without_objects(), PlanningConfig(ik_iterations=1)) as planner:
        seeded = planner.plan(q_start, tight, 'rrtconnect', 10.0, seed=3)
        seedless = planner.plan(q_start, dataclasses.replace(tight, seeds=(), seed_joints=()),
                                'rrtconnect', 1.0, seed=3)
    assert seeded.status.name == 'SUCCESS', seeded.message
    T = robot.ee_pose(seeded.path[-1]) * tight.tool_offset.to_se3()
    assert tight.contains(T)
    assert seedless.status.name == 'NO_IK_SOLUTION', seedless.message
