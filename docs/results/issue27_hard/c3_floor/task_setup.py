"""Scratch: one task as the default ``task`` attack sees it (shared by floor.py, goal_curve.py)."""
import dataclasses
import types

from advocc_ros.attack.edges import task_witness
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.task import TaskOptions
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import shared_world
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

OPTIONS = TaskOptions()


def load_task(name: str, tolerance: tuple[float, float] | None = None):
    """Scene ``name`` (goal tolerances ``(pos_m, rot_rad)`` on every axis if given), its robot,
    start, seed-0 heatmap, world, selection goals and the witness candidates of the default
    attack."""
    scene = load_scene(f'config/scenes/{name}.yaml')
    if tolerance is not None:
        pos, rot = tolerance
        scene = dataclasses.replace(scene, goal=dataclasses.replace(
            scene.goal, position_tolerance_m=(pos,) * 3, orientation_tolerance_rad=(rot,) * 3))
    robot = load_robot(scene.robot)
    q0 = start_configuration(scene, robot)
    objects = tuple(scene.objects)
    world = shared_world(robot, [sh for o in objects for sh in o.shapes])
    search = task_witness(robot, objects, q0, scene.goal, ends=OPTIONS.witness_ends,
                          seeds=OPTIONS.witness_seeds)
    return types.SimpleNamespace(
        scene=scene, robot=robot, q0=q0, objects=objects, world=world, goal=scene.goal,
        heatmap=load_heatmap(f'/tmp/s37/heatmaps/{name}_s0.npz'),
        goals=selection_goal_samples(robot, objects, scene.goal, OPTIONS.selection_samples),
        witnesses=search.candidates or ())
