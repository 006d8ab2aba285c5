"""Scratch: does the judge's goal count predict the shim's 'goal not sampled'? For kept bench
attacks: selection goals left valid (of 1,024, the judge's set), and the shim's own goal
sampler (GoalSampler, PlanningConfig, trial seeds 0..T-1) run for A attempts on the attacked
scene: converged, valid, and whether any valid goal came up. No planner runs.

argv: run folder, scene, budget, trials, attempts
"""
import json
import sys

import numpy as np

from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.obstacles import load_obstacles
from advocc_ros.kinematics.ik import GoalSampler
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.planning.types import PlanningConfig

run, name, budget, trials, attempts = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
scene = load_scene(f'config/scenes/{name}.yaml')
robot = load_robot(scene.robot)
boxes = load_obstacles(f'{run}/attacks/{name}/task_b{budget}_v0.yaml')[0]
attacked = scene.with_objects(boxes)
world0 = CollisionWorld(robot, [sh for o in scene.objects for sh in o.shapes])
world = CollisionWorld(robot, [sh for o in attacked.objects for sh in o.shapes])
sel = selection_goal_samples(robot, tuple(scene.objects), scene.goal, 1024)
sel_valid = int((~world.collisions_batch(sel.Q)).sum())
rows = []
for seed in range(trials):
    for label, w in (('unattacked', world0), ('attacked', world)):
        s = GoalSampler(robot, w.in_collision, scene.goal, np.random.default_rng(seed), PlanningConfig())
        first = None
        valid = 0
        for k in range(attempts):
            if s.attempt() is not None:
                valid += 1
                first = k if first is None else first
        rows.append((label, seed, s.converged, valid, first))
att = [r for r in rows if r[0] == 'attacked']
una = [r for r in rows if r[0] == 'unattacked']
conv = sum(r[2] for r in att)
print(json.dumps({
    'run': run, 'scene': name, 'M': budget, 'selection_valid': sel_valid, 'selection': len(sel.Q),
    'attempts_per_trial': attempts, 'trials': trials,
    'unattacked_valid_per_converged': round(sum(r[3] for r in una) / max(sum(r[2] for r in una), 1), 4),
    'attacked_converged': conv, 'attacked_valid': sum(r[3] for r in att),
    'attacked_valid_per_converged': round(sum(r[3] for r in att) / max(conv, 1), 5),
    'trials_without_valid_goal': sum(r[3] == 0 for r in att),
    'first_valid_attempt': [r[4] for r in att]}), flush=True)
