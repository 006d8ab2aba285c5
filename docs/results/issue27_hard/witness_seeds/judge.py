"""Scratch: the default task attack with witness_seeds = n, per-candidate judge scores."""
import sys, time, json
from advocc_ros.attack.edges import attack_task
from advocc_ros.attack.task import TaskOptions
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
n, seed = int(sys.argv[1]), int(sys.argv[2])
for name in sys.argv[3].split(','):
    scene = load_scene(f'config/scenes/{name}.yaml'); robot = load_robot(scene.robot)
    q0 = start_configuration(scene, robot); hm = load_heatmap(f'/tmp/s37/heatmaps/{name}_s{seed}.npz')
    t = time.perf_counter()
    r = attack_task(hm, robot, scene.objects, q0, scene.goal, 10, 'task', seed=seed,
                    goal_policy='solvable', method_options=TaskOptions(witness_seeds=n))
    st = r.stats
    print(json.dumps({'scene': name, 'n': n, 's': round(time.perf_counter() - t, 1), 'verdict': r.solvable.verdict.value,
                      'kept': st['task_witness_kept'], 'goal': [round(g * 1024) for g in st['task_witness_goal_valid']],
                      'passage': st['task_witness_passage_free']}), flush=True)
