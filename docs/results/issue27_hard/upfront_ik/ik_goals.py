"""Scratch: does the shim's up-front goal IK (8 goals or 25 % of the budget, then planning;
no goal found by then: the request fails) decide the attacked cells? The kept bench attacks
re-planned with PlanningConfig(ik_goals=K, ik_time_fraction=F).

argv: run folder, scenes (comma), budget, K:F pairs (comma), trials, planners (comma).
Trial seeds 0..trials-1 like the bench; 2 worker processes; prints one JSON row per cell.
"""
import json
import sys
import time

from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.model.scene import load_scene
from advocc_ros.planning.types import PlanningConfig
from advocc_ros.attack.obstacles import load_obstacles

run, scenes, budget = sys.argv[1], sys.argv[2].split(','), int(sys.argv[3])
ks = [(int(p.split(':')[0]), float(p.split(':')[1])) for p in sys.argv[4].split(',')]
trials, planners = int(sys.argv[5]), sys.argv[6].split(',')
for name in scenes:
    scene = load_scene(f'config/scenes/{name}.yaml')
    attacked = scene.with_objects(load_obstacles(f'{run}/attacks/{name}/task_b{budget}_v0.yaml')[0])
    for planner in planners:
        for k, frac in ks:
            t0 = time.perf_counter()
            out = evaluate_planner(attacked, planner, trials, 5.0, seed=0, workers=2,
                                   planning_config=PlanningConfig(ik_goals=k, ik_time_fraction=frac))
            recs = out['records']
            ok = [r for r in recs if r['success']]
            first = sorted(r['first_solution_s'] for r in ok)
            print(json.dumps({'scene': name, 'planner': planner, 'M': budget, 'ik_goals': k, 'ik_time_fraction': frac,
                              'psr': round(100 * len(ok) / len(recs)),
                              'statuses': sorted({r['status'] for r in recs}),
                              'fail_statuses': [r['status'] for r in recs if not r['success']],
                              'first_s_min': round(first[0], 3) if first else None,
                              'first_s_median': round(first[len(first) // 2], 3) if first else None,
                              'wall_s': round(time.perf_counter() - t0, 1)}), flush=True)
