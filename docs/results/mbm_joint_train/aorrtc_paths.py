"""Where a victim's solutions of an attacked joint-form problem run: along the certified
witness's corridor, or elsewhere (an exit of the goal the boxes left open).

usage: python aorrtc_paths.py EXPORTED_FOLDER TRIALS [VICTIM]

EXPORTED_FOLDER is one budget's folder of a built problem (``OUT/<family>/<NNNN>/m10``: the
attacked scene, the request with its joint goal, the witness). Each trial (seed k, 5 s, the raw
path: no simplification) prints one JSON line: the status, the first solution's time, and the
path's distance from the witness in joint space (both densified every 0.02 rad): its largest,
median and, over the last fifth of the path (the goal's end), largest value [rad], where along
the witness (0 start, 1 goal) the largest is, and the path's length [rad].
"""
import json
import pathlib
import sys

import numpy as np

from advocc_ros.formats.mbm_export import load_trajectory
from advocc_ros.formats.mbm_scene import load_any_scene
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.robot import load_robot
from advocc_ros.planning.types import PlanningConfig
from advocc_ros.planning.victims import VictimConfig, make_victim
from advocc_ros.planning.victims.base import Task, densify

STEP_RAD = 0.02


def main(folder: pathlib.Path, trials: int, victim_name: str) -> None:
    scene = load_any_scene(next(folder.glob('scene*.yaml')), next(folder.glob('request*.yaml')),
                           None, 'joint')
    robot = load_robot(scene.robot)
    q_start = start_configuration(scene, robot)
    names, waypoints = load_trajectory(next(folder.glob('trajectory*.yaml')))
    witness = densify(waypoints[:, [names.index(j) for j in robot.joint_names]], STEP_RAD)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(witness, axis=0), axis=1))])
    print(json.dumps({'witness_waypoints': len(waypoints), 'witness_length_rad':
                      round(float(along[-1]), 2)}))
    victim = make_victim(victim_name, VictimConfig(planning=PlanningConfig(simplify=False)))
    try:
        for seed in range(trials):
            result = victim.plan(Task(scene, q_start, scene.goal), 5.0, seed)
            row = {'victim': victim_name, 'seed': seed, 'success': result.success,
                   'first_solution_s': result.first_solution_s,
                   'validity_checks': result.stats.get('validity_checks')}
            if result.success:
                path = densify(np.asarray(result.path), STEP_RAD)
                gap = np.linalg.norm(path[:, None, :] - witness[None, :, :], axis=2)
                near, nearest = gap.min(axis=1), gap.argmin(axis=1)
                row.update(max_rad=round(float(near.max()), 3),
                           median_rad=round(float(np.median(near)), 3),
                           goal_end_max_rad=round(float(near[-len(path) // 5:].max()), 3),
                           where_max=round(float(along[nearest[near.argmax()]] / along[-1]), 2),
                           length_rad=round(float(np.linalg.norm(np.diff(path, axis=0),
                                                                 axis=1).sum()), 2))
            print(json.dumps(row), flush=True)
    finally:
        victim.close()


if __name__ == '__main__':
    main(pathlib.Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else 'aorrtc')
