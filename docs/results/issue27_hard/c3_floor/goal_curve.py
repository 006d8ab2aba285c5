"""Scratch: how many admissible boxes does it take to cover the goal set alone? (no victim planner)

Per scene and witness (argv: scenes, witness indices of ``attack_task``'s candidates, and
optionally ``POS,ROT``: the goal region's position half-extents [m] and orientation tolerances
[rad] on every axis instead of the scene's), greedy
maximum coverage of the 1,024 selection goal configurations only (uniform weights, lattice
relation, d_min, the exact C1-C3 checks and the witness guard on every pick): goal
configurations left untouched after m = 1..20 boxes. An optimistic bound for the goal term of
the attack (it covers the very set that judges it), against what the attack keeps.
"""
import json
import sys

import numpy as np

from advocc_ros.attack.configurations import cover_matrix, greedy_configurations
from advocc_ros.attack.region import search_region
from advocc_ros.attack.solvable import WitnessGuard, witness_bodies
from advocc_ros.attack.types import AttackConfig
from task_setup import load_task

cfg = AttackConfig()
tolerance = tuple(map(float, sys.argv[3].split(','))) if len(sys.argv) > 3 else None
for name in sys.argv[1].split(','):
    t = load_task(name, tolerance)
    robot, world, hm, goals = t.robot, t.world, t.heatmap, t.goals
    for i in map(int, sys.argv[2].split(',')):
        region = search_region(hm, robot, t.objects, t.q0, t.goal, cfg)
        region.guard = WitnessGuard(witness_bodies(robot, world, t.witnesses[i]),
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
