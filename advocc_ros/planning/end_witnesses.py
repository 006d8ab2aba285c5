"""Witnesses that end at given goal configurations: more witnesses for the task attack to keep.

The ``solvable`` attack leaves its witness's last configuration free, and with it every goal
configuration whose body stays near that one. Planners find the free part of the goal region by
random-seed IK (``kinematics.ik.GoalSampler``), so a witness that ends where such samples
rarely land leaves a goal set that planners rarely hit. ``attack.goals.rare_goal_configurations``
names such ends without a planner; this module finds a path to each: one RRTConnect run per
end, all in one fresh worker (the sequence is deterministic: each run stops at its first
solution), to that configuration as a one-element goal list, each path certified on the
unattacked scene like the task's own witness (``planning.witness``), and like it searched again
with the next seed (up to ``WITNESS_TRIES``) when the certificate cannot prove it (a shortcut
pulled taut against the object at the goal: measured on table_pick, 0.0996 mm from the can). An
end without a path within ``END_WITNESS_TIME_S``, or without a proven one, is dropped.

Kept like the task's witness: in this process and on disk (one file per task and end list,
``witness_cache_dir``), every witness read back certified again before it is used.
"""

from __future__ import annotations

import logging

import numpy as np

from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import Scene, SceneObject, read_yaml, save_yaml_atomic, task_hash
from advocc_ros.planning.types import PlanningConfig, PlanStatus
from advocc_ros.planning.witness import (WAYPOINT_DECIMALS, WITNESS_FORMAT, WITNESS_PLANNER,
                                         WITNESS_SEED, WITNESS_STEP_RAD, WITNESS_TRIES, Witness,
                                         certify, object_shape_names, witness_cache_dir)

log = logging.getLogger(__name__)

END_WITNESS_TIME_S = 5.0
"""Budget of the search for one end [s]; an end that needs more is dropped (the shipped scenes'
reachable ends solve in < 0.1 s)."""
END_FORMAT = 'advocc_end_witnesses'

_FOUND: BoundedCache = BoundedCache('end witnesses', 16)
"""Task and end-list hash -> tuple of witnesses found in this process."""


def find_end_witnesses(robot: RobotModel, objects: tuple[SceneObject, ...] | list,
                       q_init: np.ndarray, goal: GoalRegion, ends: np.ndarray
                       ) -> tuple[Witness, ...]:
    """Certified witnesses from ``q_init`` to the configurations ``ends`` (k, nq) on the scene
    ``objects``, in the order of ``ends``, those without a path left out (module docstring)."""
    objects = tuple(objects)
    q_init = np.asarray(q_init, float)
    ends = np.round(np.asarray(ends, float).reshape(-1, robot.nq), WAYPOINT_DECIMALS)
    if not len(ends):
        return ()
    key = task_hash(robot.hash, objects, goal, np.round(q_init, 12).tolist(), ends.tolist(),
                    WITNESS_SEED, END_WITNESS_TIME_S, END_FORMAT, WITNESS_FORMAT,
                    WITNESS_PLANNER, WITNESS_STEP_RAD, WITNESS_TRIES)
    cached = _FOUND.get(key)
    if cached is not None:
        return cached
    world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    cache_dir = witness_cache_dir()
    disk = cache_dir / f'{key}.yaml' if cache_dir is not None else None
    found = _from_disk(disk, robot, world, q_init, goal) if disk is not None else None
    if found is None:
        found = _search(robot, world, objects, q_init, goal, ends)
        if disk is not None:
            _to_disk(disk, found)
    return _FOUND.put(key, found)


def _search(robot: RobotModel, world: CollisionWorld, objects: tuple[SceneObject, ...],
            q_init: np.ndarray, goal: GoalRegion, ends: np.ndarray) -> tuple[Witness, ...]:
    from advocc_ros.planning.worker import Planner

    config = PlanningConfig(time_budget_s=END_WITNESS_TIME_S, motion_step_rad=WITNESS_STEP_RAD,
                            stop_at_first_solution=True, simplify=True, interpolate=False)
    scene = Scene(name='end witnesses', robot=robot.spec, objects=objects)
    names = object_shape_names(objects)
    with Planner(scene, config) as planner:
        found = [_certified_end(planner, robot, world, q_init, goal, q_end, i, names)
                 for i, q_end in enumerate(ends)]
    return tuple(w for w in found if w is not None)


def _certified_end(planner, robot: RobotModel, world: CollisionWorld, q_init: np.ndarray,
                   goal: GoalRegion, q_end: np.ndarray, i: int, names) -> Witness | None:
    """The first path to end ``i`` (``q_end``) of seeds ``WITNESS_SEED``, + 1, ... that the
    certificate proves; None when a search finds no path or no seed's path is proven."""
    for seed in range(WITNESS_SEED, WITNESS_SEED + WITNESS_TRIES):
        result = planner.plan(q_init, goal, WITNESS_PLANNER, END_WITNESS_TIME_S, seed,
                              goal_configs=q_end[None])
        if not result.success:
            level = log.error if result.status == PlanStatus.INTERNAL_ERROR else log.info
            level('end witness %d: no path (%s)', i, result.message)
            return None
        witness = Witness(robot.joint_names,
                          np.round(np.asarray(result.path, float), WAYPOINT_DECIMALS),
                          dict(robot.locked_values),
                          {'planner': WITNESS_PLANNER, 'seed': seed, 'end': i,
                           'time_budget_s': END_WITNESS_TIME_S,
                           'planning_time_s': round(result.planning_time_s, 4),
                           'step_rad': WITNESS_STEP_RAD})
        why = certify(robot, world, goal, witness, q_init, shape_names=names).why
        if why is None:
            return witness
        log.info('end witness %d (seed %d): not proven on the unattacked scene: %s', i, seed, why)
    return None


def _from_disk(path, robot: RobotModel, world: CollisionWorld, q_init: np.ndarray,
               goal: GoalRegion) -> tuple[Witness, ...] | None:
    """The file's witnesses if every one is certified again for this task, else None."""
    if not path.is_file():
        return None
    try:
        data = read_yaml(path)
        if not isinstance(data, dict) or data.get('format') != END_FORMAT \
                or not isinstance(data.get('witnesses'), list):
            raise SceneError(f'{path}: not an {END_FORMAT} file')
        found = tuple(Witness.from_data(w, f'{path}: witnesses[{i}]')
                      for i, w in enumerate(data['witnesses']))
    except (SceneError, OSError) as exc:
        log.warning('end witness cache: %s (searching again)', exc)
        return None
    for witness in found:
        why = certify(robot, world, goal, witness, q_init).why
        if why is not None:
            log.warning('end witness cache: %s holds a path that is no witness of this task: '
                        '%s (searching again)', path, why)
            return None
    return found


def _to_disk(path, found: tuple[Witness, ...]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_yaml_atomic(path, {'format': END_FORMAT,
                                'witnesses': [w.to_data() for w in found]})
    except OSError as exc:  # a read-only home must not fail the attack
        log.warning('end witness cache: cannot write %s (%s)', path, exc)


__all__ = ['END_WITNESS_TIME_S', 'find_end_witnesses']
