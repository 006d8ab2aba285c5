"""Where a victim's solutions of an attacked joint-form problem run: along the certified
witness's corridor, or elsewhere (an exit of the goal the boxes left open); and, with the
heatmap, whether a box the attack may place would have cut them.

usage: python aorrtc_paths.py EXPORTED_FOLDER TRIALS [VICTIM [HEATMAP]]

EXPORTED_FOLDER is one budget's folder of a built problem (``OUT/<family>/<NNNN>/m10``: the
attacked scene, the request with its joint goal, the witness). Each trial (seed k, 5 s, the raw
path: no simplification) prints one JSON line: the status, the first solution's time, and the
path's distance from the witness in joint space (both densified every 0.02 rad): its largest,
median and, over the last fifth of the path (the goal's end), largest value [rad], where along
the witness (0 start, 1 goal) the largest is, and the path's length [rad]. With HEATMAP (the
data set's robot heatmap): ``cutters``, how many of the boxes the attack may place (its search
region on the unattacked scene under the data set's settings, less those the witness's guard or
the exact checks refuse) cover a state of the path; the last line gives the box that cuts the
most solved paths and how many.
"""
import collections
import json
import pathlib
import sys

import numpy as np

from advocc_ros.attack import AttackConfig
from advocc_ros.attack.configurations import cover_matrix
from advocc_ros.attack.policy import apply_policy
from advocc_ros.attack.region import search_region
from advocc_ros.attack.types import Task as AttackTask
from advocc_ros.dataset.job import BuildConfig
from advocc_ros.formats.mbm_export import load_trajectory
from advocc_ros.formats.mbm_scene import load_any_scene
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.planning.types import PlanningConfig
from advocc_ros.planning.victims import VictimConfig, make_victim
from advocc_ros.planning.victims.base import Task, densify
from advocc_ros.planning.witness import Witness

STEP_RAD = 0.02


class Cutters:
    """The boxes the attack may place against the exported witness, and which cover a path."""

    def __init__(self, heatmap_path: str, scene, robot, q_start, names, waypoints):
        objects = tuple(o for o in scene.objects if not o.id.startswith('adv_'))
        cfg = AttackConfig(goal_policy='solvable', victim_margin_m=BuildConfig().victim_margin_m)
        task = AttackTask(robot, objects, q_start, scene.goal, 'solvable')
        region = search_region(load_heatmap(heatmap_path, robot.hash), robot, objects, q_start,
                               scene.goal, cfg)
        witness = Witness(tuple(names), waypoints, dict(robot.locked_values))
        self.region = apply_policy(task, region, cfg, (witness,), None, kept=0).region
        self.scene, self.robot, self._allowed = CollisionWorld(robot, [
            sh for o in objects for sh in o.shapes]), robot, {}
        self.centres = np.argwhere(self.region.candidates)

    def allowed(self, j: int) -> bool:
        if j not in self._allowed:
            centre = self.region.center_m(self.centres[j])
            self._allowed[j] = (self.region.box_violation(centre) is None
                                and self.region.guard.admit(centre))
        return self._allowed[j]

    def of(self, path: np.ndarray) -> set:
        cover = cover_matrix(self.robot, self.scene, path, self.region).tocsc()
        return {int(j) for j in np.unique(cover.indices) if self.allowed(int(j))}


def main(folder: pathlib.Path, trials: int, victim_name: str, heatmap: str | None) -> None:
    scene = load_any_scene(next(folder.glob('scene*.yaml')), next(folder.glob('request*.yaml')),
                           None, 'joint')
    robot = load_robot(scene.robot)
    q_start = start_configuration(scene, robot)
    names, waypoints = load_trajectory(next(folder.glob('trajectory*.yaml')))
    witness = densify(waypoints[:, [names.index(j) for j in robot.joint_names]], STEP_RAD)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(witness, axis=0), axis=1))])
    print(json.dumps({'witness_waypoints': len(waypoints), 'witness_length_rad':
                      round(float(along[-1]), 2)}))
    cutters = Cutters(heatmap, scene, robot, q_start, names, waypoints) if heatmap else None
    cut_by = []
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
                if cutters is not None:
                    cut_by.append(cutters.of(path))
                    row['cutters'] = len(cut_by[-1])
            print(json.dumps(row), flush=True)
    finally:
        victim.close()
    if cutters is not None:
        best = collections.Counter(j for boxes in cut_by for j in boxes).most_common(1)
        print(json.dumps({'solved': len(cut_by), 'best_box_cuts': best[0][1] if best else 0,
                          'best_box_center_m': cutters.region.center_m(
                              cutters.centres[best[0][0]]).round(3).tolist() if best else None}))


if __name__ == '__main__':
    main(pathlib.Path(sys.argv[1]), int(sys.argv[2]),
         sys.argv[3] if len(sys.argv) > 3 else 'aorrtc', sys.argv[4] if len(sys.argv) > 4 else None)
