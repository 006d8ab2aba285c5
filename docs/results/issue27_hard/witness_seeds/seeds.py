"""Scratch: witnesses of several searches per scene (distinct?, how long, waypoints)."""
import sys, time, json
from advocc_ros.attack.edges import task_witness
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene
n = int(sys.argv[1])
for name in ['table_pick', 'table_under_pick', 'bookshelf', 'box', 'cage']:
    scene = load_scene(f'config/scenes/{name}.yaml'); robot = load_robot(scene.robot)
    q0 = start_configuration(scene, robot)
    t = time.perf_counter()
    s = task_witness(robot, scene.objects, q0, scene.goal, ends=0, seeds=n)
    print(json.dumps({'scene': name, 's': round(time.perf_counter() - t, 2),
                      'witnesses': [(w.source['seed'], len(w.waypoints), w.source['path_length_rad']) for w in (s.witness, *s.others)]}), flush=True)
