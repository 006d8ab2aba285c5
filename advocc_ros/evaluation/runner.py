"""``evaluate_planner``: N plan requests on one scene, served by parallel planner processes."""

from __future__ import annotations

import concurrent.futures
import queue
import threading
from typing import Any

import numpy as np

from advocc_ros.evaluation.metrics import (MetricsConfig, PathInCollision, TrialRecord,
                                           aggregate, trial_metrics)
from advocc_ros.model.collision import CollisionWorld


def evaluate_planner(scene, planner_id: str, trials: int, time_budget_s: float = 5.0,
                     seed: int = 0, workers: int = 1, planning_config=None,
                     metrics_config: MetricsConfig = MetricsConfig(), progress=None,
                     victim_config=None) -> dict[str, Any]:
    """Run ``trials`` plan requests in ``scene`` and return the table row plus the records.

    ``planner_id`` names a victim (``advocc_ros.planning.victims``: an OMPL planner id or an
    outside victim such as ``mplib``). ``workers`` victims serve the trials in parallel (one
    worker process and one ``CollisionWorld`` per thread); trial ``k`` uses seed ``seed + k``.
    ``progress(record)`` is called after each trial. A success whose path collides is recorded
    as ``INTERNAL_ERROR``. Before each trial, outside the victim's clock, the trial's goal list
    is searched (``planning.goal_list``): its ``goal_found`` and ``goal_attempts`` go into the
    record and make ``psr_given_goals`` and ``no_goal_found`` of the row.
    """
    import dataclasses

    from advocc_ros.model.robot import load_robot
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.planning.victims import Task, VictimConfig, make_victim

    if scene.goal is None:
        raise ValueError(f'scene {scene.name!r} has no goal region')
    victim_config = victim_config or VictimConfig()
    if planning_config is not None:
        victim_config = dataclasses.replace(victim_config, planning=planning_config)
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    task = Task(scene, q_init, scene.goal)
    workers = max(1, min(int(workers), trials))
    planners: queue.Queue = queue.Queue()
    local = threading.local()
    started = []

    def world() -> CollisionWorld:
        if not hasattr(local, 'world'):
            local.world = CollisionWorld(robot, scene.shapes)
        return local.world

    # Before any victim's clock: each trial's goal list (the outside victims get this very list
    # from the cache), so a trial with no goal is judged as such for all, and no search shares
    # the cores with a trial.
    lists = [task.goal_list(robot, world(), victim_config.goal_configs, seed + k)
             for k in range(trials)]

    def run(k: int) -> TrialRecord:
        found = lists[k]
        planner = planners.get()
        try:
            res = planner.plan(task, time_budget_s, seed + k)
        finally:
            planners.put(planner)
        rec = TrialRecord(k, seed + k, res.success, res.status.name, float(res.planning_time_s),
                          res.message, waypoints=len(res.path),
                          first_solution_s=res.first_solution_s, goal_found=found.found,
                          goal_attempts=found.attempts)
        if res.success:
            world()
            try:
                metrics = trial_metrics(robot, local.world, res.path, q_init, metrics_config,
                                        np.random.default_rng(seed + k))
            except PathInCollision as exc:
                rec.success, rec.status = False, 'INTERNAL_ERROR'
                rec.message = f'{exc} ({res.message})'
            else:
                for key, value in metrics.items():
                    setattr(rec, key, value)
        if progress:
            progress(rec)
        return rec

    try:
        for _ in range(workers):
            planner = make_victim(planner_id, victim_config)
            started.append(planner)
            planner.start(scene)
            planners.put(planner)
        with concurrent.futures.ThreadPoolExecutor(workers) as pool:
            records = list(pool.map(run, range(trials)))
    finally:
        for planner in started:
            planner.close()
    row = aggregate(records, time_budget_s)
    return dict(row, scene=scene.name, planner=planner_id, seed=seed,
                goal_attempts=[r.goal_attempts for r in records],
                records=[r.to_data() for r in records])
