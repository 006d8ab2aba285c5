"""The paper's victim metrics (§V; docs/metrics.md): PSR, SMR, CMR, JDS, PT, and their aggregation.

Per trial (``TrialRecord``), on a successful trajectory ``path`` (N, nq) from ``q_init``:

- SMR: minimum Yoshikawa manipulability ``sqrt(det(J J^T))`` (6 x nq end-effector Jacobian)
  along the trajectory densely interpolated at ``smr_step_rad`` (0.01 rad joint space, finer
  than the 0.05 rad waypoint spacing so a dip between waypoints is not missed).
- CMR: minimum over the waypoints of an estimated joint-space distance to the invalid set: from
  each waypoint, ``cmr_directions`` random unit directions (Gaussian, normalised; fresh per
  waypoint), both signs, are marched outwards on a grid of ``cmr_coarse_step_rad`` up to
  ``cmr_range_rad``; the first invalid grid point and the free one before it bracket the
  boundary, which bisection narrows to ``cmr_resolution_rad``. Leaving the joint limits counts
  as collision (the limits bound the valid set exactly like obstacles do for OMPL); set
  ``cmr_limits_as_collision=False`` to stop rays at the limits instead. A trajectory with no
  invalid configuration within range scores ``cmr_range_rad`` (a lower bound).
  Only the minimum is needed, so all rays of all waypoints advance one grid level at a time in
  one batched collision call and the search stops at the first level where any ray is invalid:
  rays that first fail at a later level cannot beat the bracketed ones.
- JDS: mean over the waypoints of ``||q_i - q_init||`` (radians, Euclidean in joint space).
- PT: planning time [s]; a failed trial counts the full budget.

A "successful" path with a waypoint in collision is not scored (``PathInCollision``): the
planner and the metrics disagree about the scene, which is an internal error, not CMR 0.

Table rows (``aggregate``): PSR = successes / (trials - internal errors) (the task as its users
pose it), PSR given goals = the same over the trials whose goal list, found before the clock,
has a goal (``no_goal_found`` counts the others: the path search is not judged on them),
internal errors
(``advocc_ros.evaluation.outcomes``) counted on their own; SMR and CMR are reported x10^-2
(i.e. the raw value times 100), SMR/CMR/JDS averaged over successful trials, PT over the trials
that are not internal errors; SMR, CMR and JDS are ``None`` ("N/A") when PSR = 0 or undefined.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any, Iterable

import numpy as np
import pinocchio as pin

from advocc_ros.evaluation.hardness import time_summary
from advocc_ros.evaluation.outcomes import FAILURE_MODES, INTERNAL_ERROR, SUCCESS, record_outcome
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class MetricsConfig:
    """Resolution of the trajectory metrics."""

    smr_step_rad: float = 0.01
    """Joint-space interpolation step for the manipulability minimum [rad]."""
    cmr_directions: int = 16
    """Random unit directions per waypoint (each searched with both signs)."""
    cmr_range_rad: float = 0.5
    """Search range along each ray [rad]; clearances beyond it are reported as the range."""
    cmr_coarse_step_rad: float = 0.02
    """Grid step of the outward march that brackets the boundary [rad]."""
    cmr_resolution_rad: float = 1e-3
    """Bisection stops when the bracket is at most this wide [rad]."""
    cmr_limits_as_collision: bool = True
    """Leaving the joint limits counts as collision (False: rays end at the limits)."""
    threads: int = 1
    """Threads of the batched collision calls."""


@dataclasses.dataclass
class TrialRecord:
    """One plan request of an evaluation and its trajectory metrics (raw units)."""

    trial: int
    seed: int
    success: bool
    status: str
    planning_time_s: float
    message: str = ''
    min_manipulability: float | None = None
    """SMR of this trial, raw (not x10^-2)."""
    min_clearance_rad: float | None = None
    """CMR of this trial, raw [rad] (not x10^-2)."""
    jds_rad: float | None = None
    path_length_rad: float | None = None
    """Joint-space length of a success's path [rad] (OMPL's "solution length")."""
    waypoints: int = 0
    first_solution_s: float | None = None
    """Request to first exact solution [s] of a success (``PlanResult.first_solution_s``)."""
    goal_found: bool | None = None
    """Whether the goal list found before the clock (``advocc_ros.planning.goal_list``) has a
    goal: False makes the trial "no goal found", left out of ``psr_given_goals``; None: not
    searched (counted as found)."""
    goal_attempts: int | None = None
    """IK attempts that search took (how thin the valid goal set is)."""

    def to_data(self) -> dict:
        return dataclasses.asdict(self)


class PathInCollision(ValueError):
    """A path returned as a success has a waypoint in collision."""

    def __init__(self, index: int):
        super().__init__(f'the returned path\'s waypoint {index} is in collision')
        self.index = index


def densify(path: np.ndarray, step_rad: float) -> np.ndarray:
    """Path (N, nq) linearly interpolated so consecutive points are <= ``step_rad`` apart."""
    path = np.asarray(path, dtype=float)
    if len(path) < 2:
        return path
    out = [path[:1]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step_rad)))
        s = np.arange(1, n + 1)[:, None] / n
        out.append(a + s * (b - a))
    return np.concatenate(out)


def min_manipulability(robot: RobotModel, path: np.ndarray, step_rad: float = 0.01) -> float:
    """SMR (raw): minimum Yoshikawa index along the densely interpolated path."""
    data = robot.create_data()
    best = math.inf
    for q in densify(path, step_rad):
        jac = pin.computeFrameJacobian(robot.model, data, q, robot.ee_frame,
                                       pin.LOCAL_WORLD_ALIGNED)
        best = min(best, math.sqrt(max(np.linalg.det(jac @ jac.T), 0.0)))
    return float(best)


def joint_deviation(path: np.ndarray, q_init: np.ndarray) -> float:
    """JDS: mean ``||q_i - q_init||`` over the waypoints."""
    path = np.asarray(path, dtype=float)
    return float(np.mean(np.linalg.norm(path - np.asarray(q_init, float), axis=1)))


def random_directions(rng: np.random.Generator, n_waypoints: int, n_directions: int, nq: int
                      ) -> np.ndarray:
    """Rays of the CMR search, (n_waypoints, 2 * n_directions, nq): unit directions, both signs."""
    u = rng.standard_normal((n_waypoints, n_directions, nq))
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    return np.concatenate([u, -u], axis=1)


def _limit_distance(origins: np.ndarray, dirs: np.ndarray, lower, upper) -> np.ndarray:
    """Distance along each ray to the joint-limit box, (R,)."""
    with np.errstate(divide='ignore', invalid='ignore'):
        t_up = np.where(dirs > 0, (upper - origins) / dirs, np.inf)
        t_lo = np.where(dirs < 0, (lower - origins) / dirs, np.inf)
    return np.maximum(np.minimum(t_up, t_lo).min(axis=1), 0.0)


def min_clearance(world: CollisionWorld, path: np.ndarray, config: MetricsConfig = MetricsConfig(),
                  rng: np.random.Generator | None = None, directions: np.ndarray | None = None
                  ) -> float:
    """CMR (raw, rad): randomized bidirectional bisection estimate (see the module docstring).

    ``directions`` (n_waypoints, n_rays, nq) overrides the random rays (tests use it to compare
    with a brute-force line search). Raises ``PathInCollision`` when a waypoint collides.
    """
    robot = world.robot
    path = np.asarray(path, dtype=float)
    if directions is None:
        rng = rng if rng is not None else np.random.default_rng(0)
        directions = random_directions(rng, len(path), config.cmr_directions, robot.nq)
    n_rays = directions.shape[1]
    origins = np.repeat(path, n_rays, axis=0)
    dirs = directions.reshape(-1, robot.nq)
    t_lim = _limit_distance(origins, dirs, robot.lower, robot.upper)
    t_end = np.full(len(dirs), config.cmr_range_rad)
    if not config.cmr_limits_as_collision:
        t_end = np.minimum(t_end, t_lim)
        t_lim = np.full(len(dirs), np.inf)

    def invalid(idx: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether ray ``idx`` is invalid at distance ``t`` (beyond the limits or colliding)."""
        bad = t >= t_lim[idx]
        check = ~bad
        if np.any(check):
            Q = origins[idx[check]] + t[check, None] * dirs[idx[check]]
            bad[check] = world.collisions_batch(Q, config.threads)
        return bad

    colliding = np.flatnonzero(world.collisions_batch(path, config.threads))
    if len(colliding):
        raise PathInCollision(int(colliding[0]))
    h = config.cmr_coarse_step_rad
    levels = np.append(np.arange(h, config.cmr_range_rad, h), config.cmr_range_rad)
    lo_t = 0.0
    for t in levels:
        idx = np.flatnonzero(t_end >= t - 1e-12)
        if len(idx) == 0:
            break
        hit = invalid(idx, np.full(len(idx), t))
        if hit.any():
            idx = idx[hit]
            lo = np.full(len(idx), lo_t)
            hi = np.full(len(idx), t)
            while (hi - lo).max() > config.cmr_resolution_rad:
                mid = 0.5 * (lo + hi)
                bad = invalid(idx, mid)
                hi = np.where(bad, mid, hi)
                lo = np.where(bad, lo, mid)
            return float(hi.min())
        lo_t = t
    return float(config.cmr_range_rad)


def trial_metrics(robot: RobotModel, world: CollisionWorld, path: np.ndarray,
                  q_init: np.ndarray, config: MetricsConfig = MetricsConfig(),
                  rng: np.random.Generator | None = None) -> dict[str, float]:
    """SMR, CMR, JDS (raw units) and the joint-space length [rad] of one successful trajectory;
    ``PathInCollision`` if it is not collision-free."""
    path = np.asarray(path, dtype=float)
    return {'min_manipulability': min_manipulability(robot, path, config.smr_step_rad),
            'min_clearance_rad': min_clearance(world, path, config, rng),
            'jds_rad': joint_deviation(path, q_init),
            'path_length_rad': float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())}


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def aggregate(records: Iterable[TrialRecord | dict], time_budget_s: float) -> dict[str, Any]:
    """Table row of one (scene, planner, attack, budget) from per-trial records.

    ``trials`` counts every record, ``internal_errors`` those that measured nothing (left out of
    PSR, PT and the times to first solution); ``smr`` and ``cmr`` are x10^-2 (raw x 100); ``None``
    means N/A. The time to first solution (median, p90, PSR at several budgets) comes from
    ``hardness.time_summary``.
    """
    rows = [r.to_data() if isinstance(r, TrialRecord) else dict(r) for r in records]
    kinds = [record_outcome(r) for r in rows]
    valid = [r for r, kind in zip(rows, kinds) if kind != INTERNAL_ERROR]
    ok = [r for r, kind in zip(rows, kinds) if kind == SUCCESS]
    given = [kind for r, kind in zip(rows, kinds)
             if kind != INTERNAL_ERROR and r.get('goal_found') is not False]
    smr = _mean([r['min_manipulability'] for r in ok])
    cmr = _mean([r['min_clearance_rad'] for r in ok])
    return {
        'trials': len(rows),
        'internal_errors': len(rows) - len(valid),
        'successes': len(ok),
        'psr': len(ok) / len(valid) if valid else None,
        'psr_given_goals': given.count(SUCCESS) / len(given) if given else None,
        'no_goal_found': sum(1 for r in valid if r.get('goal_found') is False),
        'smr': None if smr is None else 100.0 * smr,
        'cmr': None if cmr is None else 100.0 * cmr,
        'jds': _mean([r['jds_rad'] for r in ok]),
        'pt': _mean([r['planning_time_s'] if r['success'] else time_budget_s for r in valid]),
        'time_budget_s': time_budget_s,
        'failures': {mode: kinds.count(mode) for mode in FAILURE_MODES},
        **time_summary(valid, time_budget_s),
    }


def format_value(value: float | None, digits: int = 3) -> str:
    """A table cell: ``N/A`` for undefined metrics."""
    return 'N/A' if value is None else f'{value:.{digits}f}'
