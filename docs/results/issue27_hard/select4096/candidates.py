"""Scratch: the judge's scores of every witness candidate of the default attack (seed 0,
M = 10) at a given selection size: which candidate the judge keeps, and by how much.
No victim planner (the attack's own witness searches come from the disk cache).

argv: scenes (comma), selection sizes (comma), heatmap dir pattern with {scene}
"""
import json
import sys

from advocc_ros.attack.edges import attack_task
from advocc_ros.attack.task import TaskOptions
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

for name in sys.argv[1].split(','):
    scene = load_scene(f'config/scenes/{name}.yaml')
    robot = load_robot(scene.robot)
    q0 = start_configuration(scene, robot)
    hm = load_heatmap(sys.argv[3].format(scene=name))
    for n in map(int, sys.argv[2].split(',')):
        r = attack_task(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=0,
                        goal_policy='solvable', method_options=TaskOptions(selection_samples=n))
        st = r.stats
        print(json.dumps({'scene': name, 'selection': n, 'verdict': r.solvable.verdict.value,
                          'kept': st['task_witness_kept'],
                          'goals_valid': [None if g is None else round(g * n) for g in st['task_witness_goal_valid']],
                          'passage_free': st['task_witness_passage_free'],
                          'compute_s': round(r.compute_s, 1)}), flush=True)
