"""Speed figures that ``advocc perf`` reports (measured numbers, never timed unit tests)."""

from __future__ import annotations

import os
import platform
import time
from typing import Any

import numpy as np

from advocc_ros.evaluation.outcomes import INTERNAL_ERROR, outcome
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import Scene
from advocc_ros.planning.worker import Planner
from advocc_ros.evaluation.provenance import cpu_model, validity_checks_per_s
from advocc_ros.planning.types import PlanningConfig
from advocc_ros.kinematics.ik import start_configuration


def machine() -> dict:
    """What the numbers were measured on."""
    return {'cpu': cpu_model(), 'cores': os.cpu_count(), 'python': platform.python_version()}


def benchmark_planning(scene: Scene, planner_ids=('rrtconnect', 'prmstar', 'bkpiece1'),
                       trials: int = 20, time_budget_s: float = 5.0, seed: int = 0,
                       config: PlanningConfig = PlanningConfig(), progress=None) -> dict:
    """Speed figures: validity checks/s, planning time and PSR per planner, worker overhead."""
    robot = load_robot(scene.robot)
    world = CollisionWorld(robot, scene.shapes)
    rng = np.random.default_rng(seed)
    checks_per_s = validity_checks_per_s(world, robot.sample_q(rng, 5000))
    q0 = start_configuration(scene, robot)
    out: dict[str, Any] = {'scene': scene.name, 'objects': len(scene.shapes),
                           'validity_checks_per_s_python_loop': checks_per_s,
                           'time_budget_s': time_budget_s, 'trials': trials, 'planners': {}}
    overheads = []
    with Planner(scene, config) as planner:
        t = time.perf_counter()
        planner.start()
        out['worker_start_s'] = time.perf_counter() - t
        for pid in planner_ids:
            times, ok, internal, rates = [], 0, 0, []
            for k in range(trials):
                res = planner.plan(q0, scene.goal, pid, time_budget_s, seed + k)
                if outcome(res.status.name) == INTERNAL_ERROR:  # measured nothing
                    internal += 1
                    continue
                ok += res.success
                times.append(res.planning_time_s if res.success else time_budget_s)
                if 'overhead_s' in res.stats:
                    overheads.append(res.stats['overhead_s'])
                if res.stats.get('solve_time_s'):
                    rates.append(res.stats['validity_checks'] / res.stats['solve_time_s'])
                if progress:
                    progress(pid, k, res)
            out['planners'][pid] = {
                'psr': ok / len(times) if times else None, 'internal_errors': internal,
                'median_pt_s': float(np.median(times)) if times else None,
                'mean_pt_s': float(np.mean(times)) if times else None,
                'validity_checks_per_s_in_ompl': float(np.median(rates)) if rates else None}
    out['worker_overhead_s_median'] = float(np.median(overheads)) if overheads else None
    return out
