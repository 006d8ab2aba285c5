"""Scratch: how many admissible boxes does it take to cover the goal set alone? (planner-free)

Per scene and witness (argv: scenes, witness indices of ``attack_task``'s candidates, and
optionally ``POS,ROT``: the goal region's position half-extents [m] and orientation tolerances
[rad] on every axis instead of the scene's), greedy
maximum coverage of the 1,024 selection goal configurations only (uniform weights, lattice
relation, d_min, the exact C1-C3 checks and the witness guard on every pick): goal
configurations left untouched after m = 1..20 boxes. An optimistic bound for the goal term of
the attack (it covers the very set that judges it), against what the attack keeps.
"""
import dataclasses
import json
import sys

import numpy as np

from advocc_ros.attack.configurations import cover_matrix, greedy_configurations
from advocc_ros.attack.edges import task_witness
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.region import search_region
from advocc_ros.attack.solvable import WitnessGuard, witness_bodies
from advocc_ros.attack.task import TaskOptions
from advocc_ros.attack.types import AttackConfig
from advocc_ros.heatmap.store import load_heatmap
from advocc_ros.kinematics.ik import start_configuration
from advocc_ros.model.collision import shared_world
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

opts, cfg = TaskOptions(), AttackConfig()
for name in sys.argv[1].split(','):
    scene = load_scene(f'config/scenes/{name}.yaml')
    if len(sys.argv) > 3:
        pos, rot = map(float, sys.argv[3].split(','))
        scene = dataclasses.replace(scene, goal=dataclasses.replace(
            scene.goal, position_tolerance_m=(pos,) * 3, orientation_tolerance_rad=(rot,) * 3))
    robot = load_robot(scene.robot)
    q0 = start_configuration(scene, robot)
    hm = load_heatmap(f'/tmp/s37/heatmaps/{name}_s0.npz')
    objects = tuple(scene.objects)
    world = shared_world(robot, [sh for o in objects for sh in o.shapes])
    goals = selection_goal_samples(robot, objects, scene.goal, opts.selection_samples)
    search = task_witness(robot, objects, q0, scene.goal, ends=opts.witness_ends,
                          seeds=opts.witness_seeds)
    for i in map(int, sys.argv[2].split(',')):
        region = search_region(hm, robot, objects, q0, scene.goal, cfg)
        region.guard = WitnessGuard(witness_bodies(robot, world, search.candidates[i]),
                                    region.box_size_m)
        region.guard.prune(region, hm.lut_pitch_m)
        cand = np.argwhere(region.candidates)
        cover = cover_matrix(robot, world, goals.Q, region)
        picks, _ = greedy_configurations(cover, np.ones(len(goals.Q)), region.center_m(cand),
                                         20, region.d_min_m, lambda j: region.accept(cand[j]))
        covered = np.zeros(len(goals.Q), dtype=bool)
        left = []
        cols = cover.tocsc()
        for j in picks:
            covered[cols.indices[cols.indptr[j]:cols.indptr[j + 1]]] = True
            left.append(int((~covered).sum()))
        exact = goals.valid_mask(region.center_m(cand[picks[:10]]), region.box_size_m).sum()
        print(json.dumps({'scene': name, 'tolerance': sys.argv[3] if len(sys.argv) > 3 else None,
                          'goals': len(goals.Q), 'witness': i, 'left_lattice_m1_20': left,
                          'left_exact_m10': int(exact)}), flush=True)
