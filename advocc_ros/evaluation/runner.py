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
    from advocc_ros.model.robot import load_robot
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.planning.victims import Task

    if scene.goal is None:
        raise ValueError(f'scene {scene.name!r} has no goal region')
    victim_config = _victim_config(victim_config, planning_config)
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    task = Task(scene, q_init, scene.goal)
    worlds = _ThreadWorlds(robot, scene.shapes)
    # Before any victim's clock: each trial's goal list (the outside victims get this very list
    # from the cache), so a trial with no goal is judged as such for all, and no search shares
    # the cores with a trial.
    lists = [task.goal_list(robot, worlds.get(), victim_config.goal_configs, seed + k)
             for k in range(trials)]
    planners: queue.Queue = queue.Queue()

    def run(k: int) -> TrialRecord:
        rec, path = _plan_trial(planners, task, time_budget_s, k, seed + k, lists[k])
        if rec.success:
            _judge_path(rec, path, robot, worlds.get(), q_init, metrics_config)
        if progress:
            progress(rec)
        return rec

    records = _serve(scene, planner_id, victim_config, max(1, min(int(workers), trials)),
                     planners, run, trials)
    row = aggregate(records, time_budget_s)
    return dict(row, scene=scene.name, planner=planner_id, seed=seed,
                goal_form=scene.goal.form if scene.goal is not None else None,
                goal_attempts=[r.goal_attempts for r in records],
                records=[r.to_data() for r in records])


def _victim_config(victim_config, planning_config):
    """The victims' settings: ``victim_config`` (default ``VictimConfig()``), whose planning
    settings ``planning_config`` replaces when given."""
    import dataclasses

    from advocc_ros.planning.victims import VictimConfig

    victim_config = victim_config or VictimConfig()
    if planning_config is not None:
        victim_config = dataclasses.replace(victim_config, planning=planning_config)
    return victim_config


class _ThreadWorlds:
    """One ``CollisionWorld`` per thread, built on first use: a world is not shared between
    threads, and building one per trial would cost more than the trial's checks."""

    def __init__(self, robot, shapes) -> None:
        self._robot, self._shapes = robot, shapes
        self._local = threading.local()

    def get(self) -> CollisionWorld:
        """This thread's world."""
        if not hasattr(self._local, 'world'):
            self._local.world = CollisionWorld(self._robot, self._shapes)
        return self._local.world


def _plan_trial(planners: queue.Queue, task, time_budget_s: float, k: int, trial_seed: int,
                found) -> tuple[TrialRecord, Any]:
    """Trial ``k``: plan ``task`` on a victim borrowed from ``planners`` (and given back), and
    return its record (with the goal list's ``found``) and the victim's path."""
    planner = planners.get()
    try:
        res = planner.plan(task, time_budget_s, trial_seed)
    finally:
        planners.put(planner)
    rec = TrialRecord(k, trial_seed, res.success, res.status.name, float(res.planning_time_s),
                      res.message, waypoints=len(res.path),
                      first_solution_s=res.first_solution_s, goal_found=found.found,
                      goal_attempts=found.attempts)
    return rec, res.path


def _judge_path(rec: TrialRecord, path, robot, world: CollisionWorld, q_init,
                metrics_config: MetricsConfig) -> None:
    """Fill a successful ``rec``'s path metrics, or record it as ``INTERNAL_ERROR`` when the
    path collides in ``world`` (a victim's success is not taken on trust)."""
    try:
        metrics = trial_metrics(robot, world, path, q_init, metrics_config,
                                np.random.default_rng(rec.seed))
    except PathInCollision as exc:
        rec.success, rec.status = False, 'INTERNAL_ERROR'
        rec.message = f'{exc} ({rec.message})'
    else:
        for key, value in metrics.items():
            setattr(rec, key, value)


def _serve(scene, planner_id: str, victim_config, workers: int, planners: queue.Queue, run,
           trials: int) -> list[TrialRecord]:
    """Start ``workers`` victims into ``planners``, run ``run(k)`` for every trial on as many
    threads, and close every victim started, whatever happens."""
    from advocc_ros.planning.victims import make_victim

    started = []
    try:
        for _ in range(workers):
            planner = make_victim(planner_id, victim_config)
            started.append(planner)
            planner.start(scene)
            planners.put(planner)
        with concurrent.futures.ThreadPoolExecutor(workers) as pool:
            return list(pool.map(run, range(trials)))
    finally:
        for planner in started:
            planner.close()
