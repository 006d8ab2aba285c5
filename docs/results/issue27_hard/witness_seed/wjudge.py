"""Planner-free: the judge's scores of the task attack built on the seed-0 witness and on the
new-seed witness (one witness each, 8 draws), and their selection-goal / passage numbers."""
import sys, json
from advocc_ros.attack import attack
from advocc_ros.attack.judge import judge
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.task import TaskOptions, passage_samples
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.planning.witness import find_witness, witness_states, WITNESS_SEED
from advocc_ros.attack.solvable import witness_bodies
from advocc_ros.model.collision import shared_world
name = sys.argv[1]
scene = load_scene(f'config/scenes/{name}.yaml'); robot = load_robot(scene.robot)
q0 = start_configuration(scene, robot); hm = load_heatmap(sys.argv[2])
sel = selection_goal_samples(robot, scene.objects, scene.goal, 1024)
world = shared_world(robot, [sh for o in scene.objects for sh in o.shapes])
for seed in (0, WITNESS_SEED):
    w = find_witness(robot, scene.objects, q0, scene.goal, seed=seed)
    r = attack(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=0, goal_policy='solvable',
               witness=w, method_options=TaskOptions(witness_ends=0))
    states = witness_bodies(robot, world, w).states
    j = judge(sel, passage_samples(robot, scene.objects, scene.goal, states, 4096), r.centers_m, r.box_size_m)
    print(json.dumps({'scene': name, 'witness_seed': seed, 'waypoints': len(w.waypoints),
                      'goals_valid': j.goals_valid, 'passage_free': round(j.passage_free, 3),
                      'draw_kept': r.stats.get('task_draw_kept')}), flush=True)
