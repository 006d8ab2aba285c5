"""Scratch: straight witness vs detour witnesses (start -> perturbed midpoint -> the same goal
configuration, certified on the unattacked scene); task attack M = 10 under solvable for each,
then RRTConnect / PRM* / BKPIECE1 trials in-process (5 s). Also: how many valid selection goals a
straight line from the start reaches ('direct')."""
import dataclasses, json, sys
import numpy as np
from advocc_ros.attack import attack
from advocc_ros.attack.edges import task_witness, witness_ends
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.task import TaskOptions
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.planning.solve import solve
from advocc_ros.planning.witness import certify

scene_name, seed, hm_path, trials, n_detours, det_rad = (sys.argv[1], int(sys.argv[2]), sys.argv[3],
                                                         int(sys.argv[4]), int(sys.argv[5]), float(sys.argv[6]))
scene = load_scene(f'config/scenes/{scene_name}.yaml')
robot = load_robot(scene.robot)
q0 = start_configuration(scene, robot)
hm = load_heatmap(hm_path)
base = task_witness(robot, scene.objects, q0, scene.goal, witness_ends('task', 'solvable', TaskOptions())).candidates
W0 = base[0]
free = CollisionWorld(robot, [sh for o in scene.objects for sh in o.shapes])
rng = np.random.default_rng(7)
detours = []
for _ in range(200):
    if len(detours) >= n_detours:
        break
    P = np.asarray(W0.waypoints)
    mid = 0.5 * (P[0] + P[-1]) + rng.normal(0, det_rad, P.shape[1])
    w = dataclasses.replace(W0, waypoints=np.round(np.stack([P[0], mid, P[-1]]), 12), source={'detour': det_rad})
    if certify(robot, free, scene.goal, w, q0).why is None:
        detours.append(w)
print('detours found', len(detours), flush=True)
sel = selection_goal_samples(robot, scene.objects, scene.goal, 1024)

def direct(world):
    valid = ~world.collisions_batch(sel.Q, 2)
    n = 0
    for q in sel.Q[valid]:
        k = int(np.ceil(np.linalg.norm(q - q0) / 0.01)) + 1
        n += world.first_collision(q0 + np.linspace(0, 1, k)[:, None] * (q - q0)) < 0
    return int(valid.sum()), n

def run(label, witness, opts):
    res = attack(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=seed,
                 goal_policy='solvable', witness=witness, method_options=opts)
    world = CollisionWorld(robot, [sh for o in (*scene.objects, *res.obstacles) for sh in o.shapes])
    valid, dr = direct(world)
    out = {'label': label, 'verdict': res.solvable.verdict.value if res.solvable else None,
           'boxes': len(res.obstacles), 'valid': valid, 'direct': dr, 'compute_s': round(res.compute_s, 1)}
    for planner in ('rrtconnect', 'prmstar', 'bkpiece1'):
        ok = sum(solve(robot, world, q0, scene.goal, planner, 5.0, seed=100 + k).success for k in range(trials))
        out[planner] = f'{ok}/{trials}'
    print(json.dumps(out), flush=True)

run('default (4 witnesses)', base, TaskOptions())
for i, w in enumerate(detours):
    run(f'detour {i}', w, TaskOptions(witness_ends=0))
