"""Is the goal still there? Exact goal checks under placed boxes, and the goal policies.

Every attack reports ``goal_valid_fraction``: of a fixed-seed set of goal-region IK samples
that are valid without the boxes, the fraction still valid with them (coal, exact). It tells
how a planner will fail: at 0 every goal pose is blocked (the planner reports
GOAL_IN_COLLISION); above 0 the boxes must occlude the paths.

Goal policies (docs/design.md):

- ``paper``: the paper's C3 only (d_safe from the robot at q_init and from G's position box);
  boxes may block every goal pose;
- ``reachable``: a pick is refused when it would leave fewer than ``reachable_fraction`` of the
  fixed goal samples valid, so the attack has to occlude paths rather than the goal.

The sample set depends on the task only (robot, scene, goal region; seed fixed), so it is
computed once per task and cached: every attack of one task is judged on the same samples.
A second, larger fixed set drawn the way the planners draw goals (``selection_goal_samples``)
chooses among the ``task`` attack's draws; the validation set is kept apart from it, so
``goal_valid_fraction`` is not the number the attack optimized. A third set, drawn alike from
its own seed, names the goal configurations the planners sample least often
(``rare_goal_configurations``): the ends of the extra witnesses the ``task`` attack may keep.
These two sets cost seconds of IK per task, so they are also kept on disk beside the witnesses
(``planning.witness.witness_cache_dir``); a file is used only when every configuration in it is
still a valid goal configuration of the task. The edges of an attack (``attack.edges``) sample
them first with ``workers`` > 1 (``kinematics.goal_workers``: the same sets, in worker
processes); the core finds them cached and starts no process.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import pathlib
import zipfile
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from advocc_ros.attack.bodies import LinkBoxes
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_workers import sample_goal_configurations
from advocc_ros.kinematics.ik import GoalSampler, IkConfig, goal_set
from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject, task_hash
from advocc_ros.fileio import atomic_open
from advocc_ros.planning.witness import witness_cache_dir

log = logging.getLogger(__name__)

VALIDATION_SEED = 7_345_001
"""Seed of the goal samples behind ``goal_valid_fraction`` (fixed: comparable attacks)."""
VALIDATION_SAMPLES = 32
SELECTION_SEED = 7_345_002
"""Seed of the goal samples that choose among the ``task`` attack's draws (``attack.task``):
not the validation set, so ``goal_valid_fraction`` stays an independent diagnostic."""
SELECTION_ATTEMPTS = 16
"""IK attempts per wanted sample the selection and end sets may spend (an iteration budget: the
same set on any machine)."""
PARALLEL_MIN_SAMPLES = 256
"""Goal sets this large run their IK in worker processes (~4-16 ms per sample in one)."""
END_SEED = 7_345_003
"""Seed of the goal samples among which ``rare_goal_configurations`` picks witness ends."""
END_SAMPLES = 256
RARITY_NEIGHBOUR = 5
"""The k of the k-NN distance that ranks goal configurations by rarity."""
GOALS_FORMAT = 'advocc_goal_set_1'
"""Part of the disk cache's key: a new format or sampler changes it."""

_GOAL_SAMPLES: BoundedCache = BoundedCache('goal samples', 16, per_task=True)
"""Task hash -> GoalSamples (nodes attack from several executor threads)."""
_END_SAMPLES: BoundedCache = BoundedCache('goal ends', 16, per_task=True)
"""Task hash -> the end set, rarest first (``rare_goal_configurations``)."""
_DISK = {'on': True}
"""Whether the goal sets use the disk cache (off inside :func:`sampled_afresh`)."""


class GoalSamples:
    """A fixed set of valid goal configurations and exact box checks against their bodies."""

    def __init__(self, world: CollisionWorld, Q: np.ndarray, time_cap_hit: bool = False):
        self.Q = Q
        self.time_cap_hit = time_cap_hit
        """Whether ``goal_set``'s safety cap cut the sampling short (then machine-dependent)."""
        self.bodies = LinkBoxes(world, Q)

    def blocked_by(self, center_m: np.ndarray, box_size_m: float, among=None) -> np.ndarray:
        """bool (n,): samples whose body the axis-aligned box at ``center_m`` touches (of the
        bool mask ``among`` when given; the others are False)."""
        return self.bodies.blocked_by(center_m, box_size_m, among)

    def touched_by(self, center_m: np.ndarray, box_size_m: float) -> bool:
        """Whether the box touches any sample's body (stops at the first contact)."""
        return self.bodies.touched_by(center_m, box_size_m)

    def valid_mask(self, centers_m: np.ndarray, box_size_m: float) -> np.ndarray:
        """bool (n,): the samples no box (centres (k, 3)) touches."""
        valid = np.ones(len(self.Q), dtype=bool)
        for c in np.asarray(centers_m, dtype=float).reshape(-1, 3):
            valid &= ~self.blocked_by(c, box_size_m, among=valid)
        return valid

    def valid_fraction(self, centers_m: np.ndarray, box_size_m: float) -> float | None:
        """Fraction of the samples no box touches; None without samples (no IK solution)."""
        return float(self.valid_mask(centers_m, box_size_m).mean()) if len(self.Q) else None


def goal_samples(robot: RobotModel, objects: tuple[SceneObject, ...], goal: GoalRegion,
                 n: int = VALIDATION_SAMPLES, world: CollisionWorld | None = None
                 ) -> GoalSamples:
    """The task's fixed-seed goal samples (cached per task; ~60 ms the first time, computed
    outside the lock: two threads may both compute a new task, and the first one is kept)."""
    key = task_hash(robot.hash, objects, goal, n)
    cached = _GOAL_SAMPLES.get(key)
    if cached is not None:
        return cached
    world = world or CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    sampling: dict = {}
    Q = goal_set(robot, world.collisions_batch, world.in_collision, goal, n, VALIDATION_SEED,
                 stats=sampling)
    return _GOAL_SAMPLES.put(key, GoalSamples(world, Q, sampling['goal_time_cap_hit']))


def selection_goal_samples(robot: RobotModel, objects: tuple[SceneObject, ...],
                           goal: GoalRegion, n: int, workers: int = 1) -> GoalSamples:
    """Up to ``n`` valid goal configurations drawn the way the planners draw theirs (random-seed
    IK, ``GoalSampler``; not ``goal_set``'s walks, which stay near a few IK branches), from a
    fixed seed and at most ``SELECTION_ATTEMPTS * n`` attempts; cached per task (~4-16 s of
    IK per 1,024 on the Panda scenes in one process; ``workers``: module docstring)."""
    key = task_hash(robot.hash, objects, goal, n, 'selection')
    cached = _GOAL_SAMPLES.get(key)
    if cached is not None:
        return cached
    world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    Q = _planner_like_goals(robot, world, objects, goal, n, SELECTION_SEED, workers)
    return _GOAL_SAMPLES.put(key, GoalSamples(world, Q))


def rare_goal_configurations(robot: RobotModel, objects: tuple[SceneObject, ...],
                             goal: GoalRegion, k: int, workers: int = 1) -> np.ndarray:
    """(<= k, nq): the goal configurations where the planners' goal samplers land least often,
    rarest first: of ``END_SAMPLES`` valid ones drawn like theirs (seed ``END_SEED``, not the
    selection set, which judges the attacks ending there), those farthest from their
    ``RARITY_NEIGHBOUR``-th nearest neighbour in joint space (a k-NN density estimate)."""
    if k < 1:
        return np.zeros((0, robot.nq))
    key = task_hash(robot.hash, objects, goal, END_SAMPLES, 'ends')
    Q = _END_SAMPLES.get(key)
    if Q is None:
        world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
        Q = _planner_like_goals(robot, world, objects, goal, END_SAMPLES, END_SEED, workers)
        if len(Q) > RARITY_NEIGHBOUR:
            gaps = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
            np.fill_diagonal(gaps, np.inf)
            rarity = np.sort(gaps, axis=1)[:, RARITY_NEIGHBOUR - 1]
            Q = Q[np.argsort(-rarity, kind='stable')]
        Q = _END_SAMPLES.put(key, Q)
    return Q[:k].copy()


def _planner_like_goals(robot: RobotModel, world: CollisionWorld, objects, goal: GoalRegion,
                        n: int, seed: int, workers: int) -> np.ndarray:
    """(<= n, nq) valid goal configurations from random-seed IK, at most
    ``SELECTION_ATTEMPTS * n`` attempts (an iteration budget: the same set on any machine),
    read from the disk cache when it holds them."""
    cache_dir = witness_cache_dir() if _DISK['on'] else None
    key = task_hash(robot.hash, objects, goal, n, seed, SELECTION_ATTEMPTS,
                    dataclasses.astuple(IkConfig()), GOALS_FORMAT)
    path = cache_dir / f'{key}.goals.npz' if cache_dir is not None else None
    Q = _read_goals(path, world, goal, n) if path is not None and path.exists() else None
    if Q is not None:
        return Q
    Q = _sample_goals(robot, world, goal, n, seed, workers)
    if path is not None:
        _write_goals(path, Q)
    return Q


def _sample_goals(robot: RobotModel, world: CollisionWorld, goal: GoalRegion, n: int,
                  seed: int, workers: int = 1) -> np.ndarray:
    """With ``workers`` > 1, the IK in worker processes from ``PARALLEL_MIN_SAMPLES`` on (the
    same set either way)."""
    def sampler() -> GoalSampler:
        return GoalSampler(robot, world.in_collision, goal, np.random.default_rng(seed),
                           IkConfig())

    workers = workers if n >= PARALLEL_MIN_SAMPLES else 1
    try:
        found = sample_goal_configurations(sampler(), n, SELECTION_ATTEMPTS * n, workers)
    except (OSError, BrokenProcessPool) as exc:
        log.warning('goal sampling: worker processes failed (%s): sampling in this process',
                    exc)
        found = sample_goal_configurations(sampler(), n, SELECTION_ATTEMPTS * n, 1)
    return np.array(found).reshape(-1, robot.nq)


def _read_goals(path: pathlib.Path, world: CollisionWorld, goal: GoalRegion,
                n: int) -> np.ndarray | None:
    """The cached set of ``path``, or None (with a warning) when the file is unreadable or any
    of its configurations is not a valid goal configuration of this task."""
    robot = world.robot
    try:
        with np.load(path, allow_pickle=False) as data:
            Q = np.asarray(data['Q'], dtype=float)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        log.warning('goal set cache: cannot read %s (%s): sampling again', path, exc)
        return None
    sampler = GoalSampler(robot, world.in_collision, goal, np.random.default_rng(0), IkConfig())
    valid = (Q.ndim == 2 and Q.shape[1] == robot.nq and len(Q) <= n
             and bool(np.isfinite(Q).all())
             and bool(np.all((Q >= robot.lower) & (Q <= robot.upper)))
             and not (len(Q) and world.collisions_batch(Q).any())
             and all(sampler.region_distance(q) == 0.0 for q in Q))
    if not valid:
        log.warning('goal set cache: %s does not hold valid goal configurations of this task: '
                    'sampling again', path)
        return None
    return Q


def _write_goals(path: pathlib.Path, Q: np.ndarray) -> None:
    try:
        with atomic_open(path, 'wb') as handle:
            np.savez(handle, Q=Q)
    except OSError as exc:
        log.warning('goal set cache: cannot write %s (%s)', path, exc)


@contextlib.contextmanager
def sampled_afresh():
    """Within: the goal sets neither read nor write the disk cache, so that with
    ``model.cache.clear_task_caches`` every attack samples them as for a new task (``advocc
    perf attack``'s cold timings; not for threads that attack meanwhile)."""
    _DISK['on'] = False
    try:
        yield
    finally:
        _DISK['on'] = True


class GoalGuard:
    """The ``reachable`` policy as a stateful check: ``admit`` commits the boxes it accepts."""

    reason = 'the goal policy (too many goal samples blocked)'

    def __init__(self, samples: GoalSamples, box_size_m: float, min_fraction: float):
        self.samples, self.box_size_m, self.min_fraction = samples, box_size_m, min_fraction
        self.valid = np.ones(len(samples.Q), dtype=bool)

    def admit(self, center_m: np.ndarray) -> bool:
        if not len(self.valid):
            return True
        left = self.valid & ~self.samples.blocked_by(center_m, self.box_size_m, among=self.valid)
        if left.mean() < self.min_fraction - 1e-12:
            return False
        self.valid = left
        return True


__all__ = ['GoalGuard', 'GoalSamples', 'VALIDATION_SAMPLES', 'goal_samples',
           'rare_goal_configurations', 'sampled_afresh', 'selection_goal_samples']
