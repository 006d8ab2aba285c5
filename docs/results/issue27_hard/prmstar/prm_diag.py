"""Where do PRM*'s solutions go on an attacked task that RRTConnect times out on?
box, seed 2000, 16 draws / 4 per end (PRM* 90 %, RRTConnect 10 % in the bench)."""
import json, sys, time
import numpy as np
from advocc_ros.attack import attack
from advocc_ros.attack.edges import task_witness, witness_ends
from advocc_ros.attack.task import TaskOptions
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.model.collision import shared_world
from advocc_ros.planning.solve import solve
from advocc_ros.planning.witness import witness_states

scene_name, seed, draws, ends, trials = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
hm_path = sys.argv[6]
scene = load_scene(f'config/scenes/{scene_name}.yaml')
robot = load_robot(scene.robot)
q0 = start_configuration(scene, robot)
opts = TaskOptions(draws=draws, end_draws=ends)
cands = task_witness(robot, scene.objects, q0, scene.goal, witness_ends('task', 'solvable', opts)).candidates
hm = load_heatmap(hm_path)
res = attack(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=seed, goal_policy='solvable',
             witness=cands, method_options=opts)
print('attack', res.status.value, res.solvable.verdict if res.solvable else None, 'kept witness',
      res.stats.get('task_witness_kept'), 'draw', res.stats.get('task_draw_kept'))
print('centers', np.round(res.centers_m, 2).tolist())
W = witness_states(res.witness.waypoints, 0.02)
W = np.asarray(W)
print('witness waypoints', len(res.witness.waypoints), 'states', len(W))
world = shared_world(robot, [sh for o in (*scene.objects, *res.obstacles) for sh in o.shapes])
rows = []
for planner in ('prmstar', 'rrtconnect'):
    for k in range(trials):
        r = solve(robot, world, q0, scene.goal, planner, 5.0, seed=k)
        row = {'planner': planner, 'seed': k, 'status': r.status.value, 'first_s': r.first_solution_s}
        if r.success:
            P = np.asarray(r.path)
            d = np.abs(P[:, None, :] - W[None, :, :]).max(axis=2).min(axis=1)  # Linf to the witness
            row.update(max_dev=float(d.max()), mean_dev=float(d.mean()),
                       end_dev=float(np.abs(P[-1] - W[-1]).max()), n=len(P))
        rows.append(row)
        print(json.dumps(row), flush=True)
