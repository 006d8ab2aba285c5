"""Scratch: how far can ANY set of admissible boxes narrow a task? (no victim planner)

Per scene (seed-0 heatmap), on the attack's own lattice relation (``cover_matrix``: a box
covers a configuration when a voxel centre inside the robot lies in the box's voxel cube):

- c3: the candidate centres C1-C3 admit (``search_region``, the paper's region);
- per witness candidate of the default attack (task's witness + 4 more searches + 3 rare
  ends, the ones ``attack_task`` would hand the attack): the same candidates after the
  ``solvable`` guard of that witness (``WitnessGuard.prune``).

For each: of the 1,024 selection goal configurations (drawn like the planners' goal samplers)
and of the 4,096 tight-tube configurations around the witness (``passage_samples``), the
fraction NO admissible box touches, whatever the budget: a floor under ``goal valid`` and
``passage free`` for every attack under these constraints.
"""
import json
import sys
import time

import numpy as np

from advocc_ros.attack.configurations import cover_matrix
from advocc_ros.attack.region import search_region
from advocc_ros.attack.solvable import WitnessGuard, witness_bodies
from advocc_ros.attack.task import passage_samples
from advocc_ros.attack.types import AttackConfig
from task_setup import OPTIONS, load_task


def untouched(robot, world, Q, region):
    cover = cover_matrix(robot, world, Q, region)
    return float(np.mean(cover.getnnz(axis=1) == 0)) if len(Q) else None


cfg = AttackConfig()
for name in sys.argv[1].split(','):
    t0 = time.perf_counter()
    t = load_task(name)
    robot, world, hm = t.robot, t.world, t.heatmap
    region = search_region(hm, robot, t.objects, t.q0, t.goal, cfg)
    row = {'scene': name, 'candidates_c3': int(region.candidates.sum()),
           'goals': len(t.goals.Q),
           'goal_untouchable_c3': untouched(robot, world, t.goals.Q, region)}
    rows = []
    for i, w in enumerate(t.witnesses):
        r = search_region(hm, robot, t.objects, t.q0, t.goal, cfg)
        bodies = witness_bodies(robot, world, w)
        WitnessGuard(bodies, r.box_size_m).prune(r, hm.lut_pitch_m)
        tube = passage_samples(robot, t.objects, t.goal, bodies.states, OPTIONS.passage_samples)
        rows.append({'witness': i, 'candidates': int(r.candidates.sum()),
                     'goal_untouchable': untouched(robot, world, t.goals.Q, r),
                     'passage_untouchable': untouched(robot, world, tube.Q, r)})
    row['witnesses'] = rows
    row['s'] = round(time.perf_counter() - t0, 1)
    print(json.dumps(row), flush=True)
