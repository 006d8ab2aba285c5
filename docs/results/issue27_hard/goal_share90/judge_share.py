"""Scratch: would the judge pick the better goal share per scene? (no victim planner)

The seed-0, M = 10 attack at goal_share 0.5 and 0.9 per scene; the kept candidate's judge
scores (selection goals left valid of 1,024, passage free), to compare with the measured PSRs. The only planner runs are the attack's own witness
searches (cached on disk from the benches).
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
    hm = load_heatmap(f'/tmp/s37/heatmaps/{name}_s0.npz')
    for share in (0.5, 0.9):
        r = attack_task(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=0,
                        goal_policy='solvable', method_options=TaskOptions(goal_share=share))
        st, k = r.stats, r.stats['task_witness_kept']
        print(json.dumps({'scene': name, 'goal_share': share, 'verdict': r.solvable.verdict.value,
                          'kept': k, 'goals_valid': round(st['task_witness_goal_valid'][k] * 1024),
                          'passage_free': st['task_witness_passage_free'][k]}), flush=True)
