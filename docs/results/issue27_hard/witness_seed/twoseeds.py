"""Scratch: the task attack with the new-seed witness, the seed-0 witness and the rare ends as
candidates (the judge keeps one), then 20 trials x 5 s per planner (trial seeds 100 + k)."""
import sys, json
from advocc_ros.attack import attack
from advocc_ros.attack.edges import task_witness
from advocc_ros.attack.task import TaskOptions
from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
from advocc_ros.planning.witness import find_witness
name = sys.argv[1]
scene = load_scene(f'config/scenes/{name}.yaml'); robot = load_robot(scene.robot)
q0 = start_configuration(scene, robot); hm = load_heatmap(sys.argv[2])
search = task_witness(robot, scene.objects, q0, scene.goal, 3)
w0 = find_witness(robot, scene.objects, q0, scene.goal, seed=0)
cands = (search.witness, w0, *search.ends)
r = attack(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=0, goal_policy='solvable',
           witness=cands, method_options=TaskOptions())
out = {'scene': name, 'verdict': r.solvable.verdict.value, 'kept': r.stats['task_witness_kept'],
       'goal_valid': r.stats['task_witness_goal_valid'], 'passage': r.stats['task_witness_passage_free']}
attacked = scene.with_objects(r.obstacles)
for p in ('rrtconnect', 'prmstar', 'bkpiece1'):
    row = evaluate_planner(attacked, p, 20, 5.0, seed=100, workers=2)
    out[p] = row['psr']
print(json.dumps(out), flush=True)
