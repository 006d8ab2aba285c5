"""Planning requests and answers: planner ids, settings, status codes, results (no OMPL)."""

from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np

from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion


class PlanStatus(enum.IntEnum):
    """Outcome of a plan request; values of moveit_msgs/MoveItErrorCodes (and advocc_msgs')."""

    SUCCESS = 1
    PLANNING_FAILED = -1
    INVALID_MOTION_PLAN = -2
    """The solution has a waypoint in collision (MoveIt's ``ValidateSolution`` answers the
    same): the planner's motion check stepped over an obstacle it then interpolated into."""
    TIMED_OUT = -6
    START_STATE_IN_COLLISION = -10
    GOAL_IN_COLLISION = -12
    INVALID_GOAL_CONSTRAINTS = -16
    INVALID_ROBOT_STATE = -17
    GOAL_STATE_INVALID = -27
    """None of the goal configurations handed to a victim is valid in the victim's own collision
    model (its model differs from ours): a failure of the task in that model, not of the
    planner."""
    NO_IK_SOLUTION = -31
    INVALID_REQUEST = -101
    UNKNOWN_METHOD = -102
    INTERNAL_ERROR = -105
    MODEL_MISMATCH = -106
    """An outside victim's path is collision-free in its own model (e.g. MPlib's meshes) but
    collides in ours (the convex hulls the attack and the certificate use): reported on its
    own, never counted as a success."""
    """The planner itself failed (an exception, a dead worker): the trial says nothing about
    the scene, so it must never count as a planning failure."""


REQUEST_ERRORS = frozenset({
    PlanStatus.INVALID_REQUEST, PlanStatus.UNKNOWN_METHOD, PlanStatus.INVALID_ROBOT_STATE,
    PlanStatus.INVALID_GOAL_CONSTRAINTS, PlanStatus.START_STATE_IN_COLLISION})
"""Outcomes that say the request is wrong, not that the planner failed: a benchmark and a
planner-in-the-loop attack stop on them instead of counting them as attack wins."""


# OMPL geometric planners selectable by name (lower-case id -> class name in ompl.geometric).
# All of them solve the problem as set up here (goal region, default projection for KPIECE/SBL).
# AORRTC exists only in OMPL 2: the ``aorrtc`` victim plans with it in its own venv.
_PLANNER_CLASSES = (
    'RRTConnect', 'PRMstar', 'BKPIECE1', 'RRT', 'RRTstar', 'TRRT', 'LazyRRT', 'InformedRRTstar',
    'SORRTstar', 'RRTsharp', 'RRTXstatic', 'LBTRRT', 'PRM', 'LazyPRM', 'LazyPRMstar', 'KPIECE1',
    'LBKPIECE1', 'EST', 'BiEST', 'ProjEST', 'SBL', 'STRIDE', 'PDST', 'FMT', 'BFMT', 'BITstar',
    'ABITstar', 'AITstar', 'EITstar', 'SST', 'SPARS', 'SPARStwo', 'AORRTC')
PLANNERS: dict[str, str] = {name.lower(): name for name in _PLANNER_CLASSES}


def planner_class_name(planner_id: str) -> str | None:
    """OMPL class name for a planner id (``rrtconnect``, ``RRTConnectkConfigDefault``, ...)."""
    key = planner_id.strip().lower()
    key = key.removeprefix('geometric::').removesuffix('kconfigdefault')
    return PLANNERS.get(key)


@dataclasses.dataclass(frozen=True)
class PlanningConfig:
    """How plan requests are solved; defaults are the paper's (§V-A) and MoveIt's."""

    time_budget_s: float = 5.0
    """Default wall-clock budget of one request [s]: IK goal sampling + solve + simplify."""
    max_time_budget_s: float = 600.0
    """Largest budget a request may ask for [s]."""
    motion_step_rad: float = 0.01
    """Joint-space distance between validity checks along a motion [rad] (L2, OMPL's
    ``validSegmentCount`` rule). OMPL's resolution is set to ``motion_step_rad / max_extent``.
    The planners check states only: how far a link point can move between two checks is
    ``RobotModel.motion_bound.max_m_per_rad`` times this step (computed per robot when the
    model loads). For every shipped arm that distance is below the default box edge, so a
    motion cannot step over a box (test_motion_bound checks it); MoveIt's default resolution
    (0.005 * extent) could. A witness is not trusted to this step:
    ``advocc_ros.planning.certificate`` proves the continuous path."""
    ik_goals: int = 8
    """Goal configurations sampled by IK before planning starts."""
    max_goals: int = 64
    """Cap on goal configurations, including those sampled lazily while planning."""
    ik_time_fraction: float = 0.25
    """Share of the budget that up-front IK sampling may use."""
    ik_iterations: int = 100
    """Damped-least-squares iterations per IK attempt (one random seed)."""
    ik_damping: float = 1e-4
    """DLS damping lambda^2 (keeps steps bounded near singularities)."""
    simplify: bool = True
    """Shortcut and smooth the solution like MoveIt's default ``simplify_solutions: true``."""
    interpolate: bool = True
    """Interpolate the solution like MoveIt's default (waypoints at most
    ``waypoint_step_rad`` apart and at least ``min_waypoints``)."""
    waypoint_step_rad: float = 0.05
    """Maximum joint-space distance between returned waypoints [rad]."""
    min_waypoints: int = 10
    """Minimum number of returned waypoints (MoveIt's ``minimum_waypoint_count``)."""
    stop_at_first_solution: bool = False
    """Optimizing planners (PRM*, RRT*, BIT*) keep improving until the budget ends, as in
    MoveIt; True makes them return their first solution."""
    projection_joints: tuple[int, ...] = (0, 1)
    """Joints of the KPIECE/SBL projection (MoveIt's ``joints(panda_joint1,panda_joint2)``)."""
    watchdog_margin_s: float = 2.0
    """The watchdog kills a worker that has not answered ``budget + margin`` after a request."""
    worker_start_timeout_s: float = 120.0
    """Time a new worker may take to import its libraries and load the robot [s]."""

    def __post_init__(self):
        positive = ('time_budget_s', 'max_time_budget_s', 'motion_step_rad', 'ik_damping',
                    'waypoint_step_rad', 'watchdog_margin_s', 'worker_start_timeout_s')
        checks = {name: _finite_number(getattr(self, name)) and getattr(self, name) > 0
                  for name in positive}
        checks.update({name: _whole(getattr(self, name)) and getattr(self, name) >= 1
                       for name in ('ik_goals', 'max_goals', 'ik_iterations')})
        checks['min_waypoints'] = _whole(self.min_waypoints) and self.min_waypoints >= 2
        checks['ik_time_fraction'] = (_finite_number(self.ik_time_fraction)
                                      and 0 < self.ik_time_fraction <= 1)
        checks['time_budget_s'] = (checks['time_budget_s'] and checks['max_time_budget_s']
                                   and self.time_budget_s <= self.max_time_budget_s)
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f'planning parameter {name}={getattr(self, name)!r} is out '
                                 'of range')


def _finite_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclasses.dataclass
class PlanResult:
    """Answer to one plan request."""

    status: PlanStatus
    message: str
    path: np.ndarray
    """(N, nq) waypoints from the start to a goal configuration; (0, nq) on failure."""
    planning_time_s: float
    """Wall time spent in the worker: IK goal sampling + solve + post-processing [s]."""
    stats: dict = dataclasses.field(default_factory=dict)
    """Diagnostics: validity checks, goal configurations, request round trip, ...; a success
    has ``first_solution_s``: request to first exact solution [s], before simplification (PRM*
    and other optimizing planners run on to the budget after it)."""

    @property
    def success(self) -> bool:
        return self.status == PlanStatus.SUCCESS

    @property
    def first_solution_s(self) -> float | None:
        """Time to the first solution [s]: None on failure, ``planning_time_s`` when the solver
        did not record it (an answer that came without stats)."""
        if not self.success:
            return None
        return float(self.stats.get('first_solution_s', self.planning_time_s))

    def to_data(self) -> dict:
        return {'status': int(self.status), 'message': self.message,
                'path': np.asarray(self.path, float).tolist(),
                'planning_time_s': float(self.planning_time_s), 'stats': self.stats}

    @classmethod
    def from_data(cls, data: dict, nq: int) -> 'PlanResult':
        path = np.asarray(data.get('path') or np.zeros((0, nq)), float).reshape(-1, nq)
        return cls(PlanStatus(int(data['status'])), str(data['message']), path,
                   float(data['planning_time_s']), dict(data.get('stats', {})))


def failed(status: PlanStatus, message: str, nq: int, elapsed: float = 0.0, **stats
           ) -> PlanResult:
    """A plan that did not succeed: ``status`` and ``message``, no path ((0, nq)), ``elapsed``
    seconds and ``stats``; every planner and victim reports its failures through it."""
    return PlanResult(status, message, np.zeros((0, nq)), elapsed, stats)


def validate_request(robot: RobotModel, q_start, goal: GoalRegion, planner_id: str,
                     time_budget_s: float, config: PlanningConfig = PlanningConfig()
                     ) -> PlanResult | None:
    """An error result for a malformed request, or None; cheap, needs no collision world."""
    nq = robot.nq
    q = np.asarray(q_start, dtype=float)
    if q.shape != (nq,):
        return failed(PlanStatus.INVALID_ROBOT_STATE,
                      f'start state: expected {nq} joint values, got shape {q.shape}', nq)
    if not np.all(np.isfinite(q)):
        return failed(PlanStatus.INVALID_REQUEST, f'start state: non-finite values {q.tolist()}',
                      nq)
    if not robot.within_limits(q):
        bad = [robot.joint_names[i] for i in np.flatnonzero(
            (q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))]
        return failed(PlanStatus.INVALID_ROBOT_STATE,
                      f'start state: joints {bad} outside their limits', nq)
    if planner_class_name(planner_id) is None:
        return failed(PlanStatus.UNKNOWN_METHOD,
                      f'unknown planner {planner_id!r}; known: {sorted(PLANNERS)}', nq)
    if not (isinstance(time_budget_s, (int, float)) and math.isfinite(time_budget_s)
            and 0 < time_budget_s <= config.max_time_budget_s):
        return failed(PlanStatus.INVALID_REQUEST, f'time budget {time_budget_s!r} s: expected '
                      f'0 < budget <= {config.max_time_budget_s}', nq)
    if not robot.model.existFrame(goal.link):
        return failed(PlanStatus.INVALID_GOAL_CONSTRAINTS,
                      f'goal region link {goal.link!r} is not a link of the robot', nq)
    return None
