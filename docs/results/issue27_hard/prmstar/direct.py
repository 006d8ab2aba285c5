"""Planner-free: of the goal configurations an attack leaves valid (1,024 selection samples), how
many does a straight joint-space line from the start reach without collision? Against PRM* PSR."""
import re, sys, pathlib
import numpy as np
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.obstacles import load_obstacles
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

def psr(run, scene):
    t = pathlib.Path(run, 'table1.md').read_text()
    out = {}
    for line in t.splitlines():
        if f'({scene})' in line and '| Task |' in line:
            cells = [c.strip() for c in line.split('|')]
            out[cells[2]] = cells[4]
    return out

for run in sys.argv[1:]:
    for f in sorted(pathlib.Path(run, 'attacks').glob('*/task_b10_v0.yaml')):
        scene_name = f.parent.name
        scene = load_scene(f'config/scenes/{scene_name}.yaml')
        robot = load_robot(scene.robot)
        q0 = start_configuration(scene, robot)
        boxes, _ = load_obstacles(f)
        sel = selection_goal_samples(robot, scene.objects, scene.goal, 1024)
        world = CollisionWorld(robot, [sh for o in (*scene.objects, *boxes) for sh in o.shapes])
        valid = ~world.collisions_batch(sel.Q, 2)
        direct = 0
        for q in sel.Q[valid]:
            n = int(np.ceil(np.linalg.norm(q - q0) / 0.01)) + 1
            Q = q0 + np.linspace(0, 1, n)[:, None] * (q - q0)
            direct += world.first_collision(Q) < 0
        print(f'{pathlib.Path(run).name:28s} {scene_name:17s} valid {int(valid.sum()):4d} direct {direct:4d}  PSR {psr(run, scene_name)}', flush=True)
