"""The goal sampler's attempts, many at once: goal configurations drawn the way the planners
draw theirs.

The planners' goal sampler (``kinematics.ik.GoalSampler``) makes one attempt at a time from one
seeded stream. :func:`planner_goals` makes the same attempts, from the same stream, with the same
DLS steps, in batches through ``kinematics.batch``, and keeps the collision-free ones: a sample
of the goal set as the victims see it (where their samples land often, and where rarely), at a
few milliseconds per thousand attempts instead of seconds. It is the one way goal
configurations are drawn outside the planners' clock: the attack's task sample
(:func:`task_goals`), the goal checks (``attack.goals``), the goal probe
(``attack.solvable``), the victims' goal lists (``planning.goal_list``, with anchors) and the
tests.

The attempts follow one seeded stream and an attempt budget (``attempts_per_sample * n``),
never a clock, so a seed gives the same set on any machine. The task's sample
(:func:`task_goals`) is kept in the process and on disk beside the task's witness
(``model.cache.disk_cache_dir``); a file is used only when every configuration in it is still a
collision-free goal configuration of the task.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import zipfile
from typing import Callable

import numpy as np

from advocc_ros.kinematics.batch import ChainKinematics, dls
from advocc_ros.kinematics.ik import BATCH, GoalSampler, IkConfig, goal_box
from advocc_ros.fileio import atomic_open
from advocc_ros.limits import worker_threads
from advocc_ros.model.cache import BoundedCache, disk_cache_dir
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import task_hash

log = logging.getLogger(__name__)

THREADS = worker_threads()
"""Threads of the batched collision checks (C++); the result does not depend on it."""
ATTEMPTS_PER_SAMPLE = 16
"""Attempt budget per wanted sample (narrow regions in cluttered scenes need many)."""
TASK_GOALS = 1024
"""Size of the task's goal sample (:func:`task_goals`): the resolution at which the attack
sees the goal set; a planner draws a few hundred goals in a 5 s budget, so a set left valid on
under 1 of 1,024 samples is one it rarely hits."""
TASK_GOAL_SEED = 7_345_002
"""Seed of the task's goal sample: part of the task, not of one attack."""
GOALS_FORMAT = 'advocc_goal_sample_1'
"""Part of the disk cache's key: a new format or sampler changes it."""
RARITY_NEIGHBOUR = 5
"""The k of the k-NN distance that ranks goal configurations by rarity."""

TASK_GOAL_SAMPLES: BoundedCache = BoundedCache('task goals', 16, per_task=True)
"""Task hash -> GoalDraw (nodes attack from several executor threads)."""


@dataclasses.dataclass(frozen=True)
class GoalDraw:
    """Valid goal configurations and what it took to find them."""

    Q: np.ndarray
    """(k <= n, nq) collision-free configurations with the tool inside the region."""
    attempts: int
    converged: int
    """Attempts whose IK reached the region (valid or not)."""


def planner_goals(robot: RobotModel, goal: GoalRegion,
                  collisions_batch: Callable[[np.ndarray], np.ndarray], n: int, seed,
                  attempts_per_sample: int = ATTEMPTS_PER_SAMPLE, config=IkConfig(),
                  enough: int | None = None, anchors: np.ndarray | None = None) -> GoalDraw:
    """Up to ``n`` valid goal configurations from ``seed`` (an integer or a sequence of them:
    ``numpy.random.default_rng``'s), the module docstring; with ``enough``, it stops after the
    first batch that brings the count to ``enough``; ``anchors``: configurations the stream
    offers and walks near, besides the region's seeds (``GoalSampler``)."""
    sampler = GoalSampler(robot, None, goal, np.random.default_rng(seed), config, anchors)
    chain = ChainKinematics(robot.model, sampler.frame)
    found, attempts, converged = [], 0, 0
    budget = attempts_per_sample * n
    wanted = n if enough is None else min(enough, n)
    while sum(len(f) for f in found) < wanted and attempts < budget:
        k = min(BATCH, budget - attempts)
        starts, targets, iterations = sampler.draw(k)
        if chain.supports:
            Q, ok = dls(chain, starts, targets, iterations, config.ik_damping,
                        GoalSampler.max_step_rad, robot.lower, robot.upper, sampler.box)
        else:  # the same attempts, one at a time through pinocchio
            solved = [sampler.solve(*row) for row in zip(starts, targets, iterations)]
            ok = np.array([q is not None for q in solved], dtype=bool)
            Q = np.array([starts[i] if q is None else q for i, q in enumerate(solved)])
        Q = Q[ok]
        converged += len(Q)
        if len(Q):
            found.append(Q[~collisions_batch(Q)])
        attempts += k
    Q = np.concatenate(found)[:n] if found else np.zeros((0, robot.nq))
    return GoalDraw(Q.reshape(-1, robot.nq), attempts, converged)


def task_goals(robot: RobotModel, objects, goal: GoalRegion, n: int = TASK_GOALS) -> GoalDraw:
    """The task's fixed goal sample (``planner_goals`` from ``TASK_GOAL_SEED`` on the scene
    ``objects``), cached per task: the attack covers it and the witness search picks its end
    from it."""
    key = task_hash(robot.hash, tuple(objects), goal, n, TASK_GOAL_SEED, BATCH,
                    ATTEMPTS_PER_SAMPLE, dataclasses.astuple(IkConfig()), GOALS_FORMAT)

    def make() -> GoalDraw:
        world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])

        def collisions(Q: np.ndarray) -> np.ndarray:
            return world.collisions_batch(Q, THREADS)
        cache_dir = disk_cache_dir()
        path = cache_dir / f'{key}.goals.npz' if cache_dir is not None else None
        draw = _read(path, robot, goal, collisions, n) if path is not None else None
        if draw is None:
            draw = planner_goals(robot, goal, collisions, n, TASK_GOAL_SEED)
            if path is not None:
                _write(path, draw)
        return draw
    return TASK_GOAL_SAMPLES.get_or_make(key, make)


POCKET_SEED = 7_345_003
"""Seed of the pocket sample: part of the task, not of one attack."""


def goal_pocket(robot: RobotModel, world: CollisionWorld, goal: GoalRegion, samples: int,
                rad: float) -> np.ndarray:
    """(k <= ``samples``, nq) collision-free configurations within the joint limits around a
    ``joint`` goal (its configuration plus N(0, ``rad``) per joint, seed ``POCKET_SEED``):
    where every path to the goal ends, so the boxes that cover them narrow its last passage."""
    q_goal = goal.configuration(robot.joint_names)
    rng = np.random.default_rng(POCKET_SEED)
    Q = q_goal + rng.normal(0.0, rad, (samples, robot.nq))
    Q = Q[np.all((Q >= robot.lower) & (Q <= robot.upper), axis=1)]
    return Q[~world.collisions_batch(Q, THREADS)] if len(Q) else Q


RAY_RANGE_FRACTION = 0.2
"""An RRT's step, as a fraction of the joint space's diagonal: OMPL's default ``range``
(``SelfConfig::configurePlannerRange``), which RRTConnect and AORRTC take unless told."""
RAY_STEP_RAD = 0.05
"""Spacing of the configurations checked along a goal ray [rad]."""


def goal_ray_ends(robot: RobotModel, q_goal: np.ndarray, rays: int, draw: int = 0
                  ) -> np.ndarray:
    """(rays, nq) ends of an RRT's first steps from ``q_goal``: towards uniform states within
    the joint limits, cut at OMPL's default range (:data:`RAY_RANGE_FRACTION`); seed
    ``POCKET_SEED`` (and ``draw`` after 0), so a task's rays of a draw are the same each
    time."""
    rng = np.random.default_rng((POCKET_SEED, draw) if draw else POCKET_SEED)
    reach = RAY_RANGE_FRACTION * float(np.linalg.norm(robot.upper - robot.lower))
    target = robot.lower + (robot.upper - robot.lower) * rng.random((rays, robot.nq))
    offset = target - q_goal
    length = np.linalg.norm(offset, axis=1)
    return q_goal + offset * np.minimum(1.0, reach / np.maximum(length, 1e-12))[:, None]


def free_rays(world: CollisionWorld, q_goal: np.ndarray, ends: np.ndarray,
              step_rad: float = RAY_STEP_RAD) -> np.ndarray:
    """Mask of the straight motions from ``q_goal`` to the rows of ``ends`` with no
    configuration in collision every ``step_rad`` (the goal itself not checked), checked
    outwards from the goal in batches, so that a ray costs the checks up to its first
    collision (most hit something close to a goal the scene closes in on)."""
    steps = np.maximum(np.ceil(np.linalg.norm(ends - q_goal, axis=1) / step_rad), 1)
    free = np.ones(len(ends), dtype=bool)
    for k in range(1, int(steps.max(initial=0)) + 1):
        alive = np.flatnonzero(free & (steps >= k))
        if not len(alive):
            break
        t = (k / steps[alive])[:, None]
        Q = q_goal + t * (ends[alive] - q_goal)
        free[alive[world.collisions_batch(Q, THREADS)]] = False
    return free


def _read(path: pathlib.Path, robot: RobotModel, goal: GoalRegion, collisions, n: int
          ) -> GoalDraw | None:
    """The sample kept in ``path`` if it still is one of this task (else None, with a warning
    when the file exists)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            Q = np.asarray(data['Q'], dtype=float)
            attempts, converged = int(data['attempts']), int(data['converged'])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        log.warning('goal sample cache: cannot read %s (%s): sampling again', path, exc)
        return None
    chain = ChainKinematics(robot.model, robot.model.getFrameId(goal.link))
    valid = (Q.ndim == 2 and Q.shape[1] == robot.nq and len(Q) <= n
             and bool(np.isfinite(Q).all())
             and bool(np.all((Q >= robot.lower) & (Q <= robot.upper))))
    if valid and len(Q):
        in_region = (goal_box(robot, goal).contains(chain.frame(Q)) if chain.supports
                     else np.ones(len(Q), bool))
        valid = bool(in_region.all()) and not collisions(Q).any()
    if not valid:
        log.warning('goal sample cache: %s does not hold goal configurations of this task: '
                    'sampling again', path)
        return None
    return GoalDraw(Q, attempts, converged)


def _write(path: pathlib.Path, draw: GoalDraw) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_open(path, 'wb') as handle:
            np.savez(handle, Q=draw.Q, attempts=draw.attempts, converged=draw.converged)
    except OSError as exc:  # a read-only home must not fail the attack
        log.warning('goal sample cache: cannot write %s (%s)', path, exc)


def rarest_first(Q: np.ndarray, k: int = RARITY_NEIGHBOUR) -> np.ndarray:
    """Indices of ``Q`` (n, nq) by decreasing distance to their ``k``-th nearest neighbour in
    joint space: where a sampler that drew ``Q`` lands least often comes first."""
    if len(Q) <= k:
        return np.arange(len(Q))
    d2 = np.sum((Q[:, None, :] - Q[None, :, :]) ** 2, axis=2)
    kth = np.partition(d2, k, axis=1)[:, k]  # column 0 is the point itself
    return np.argsort(-kth, kind='stable')


__all__ = ['ATTEMPTS_PER_SAMPLE', 'GoalDraw', 'POCKET_SEED', 'RAY_RANGE_FRACTION', 'RAY_STEP_RAD',
           'TASK_GOALS', 'TASK_GOAL_SAMPLES', 'free_rays', 'goal_pocket', 'goal_ray_ends',
           'planner_goals', 'rarest_first', 'task_goals']
