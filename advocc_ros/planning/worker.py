"""Motion planning with OMPL to tolerance-aware goal regions, run in a watched worker process.

The victim side of the evaluation (paper §V-A, SPEC §4): OMPL geometric planners over the arm
joints (``RealVectorStateSpace`` with the joint limits), a validity checker built on
``CollisionWorld`` (SRDF self-collision + scene), and a goal region reached by sampling goal
configurations with damped-least-squares IK inside the region.

Why a worker process. OMPL's ``solve`` runs in C++ and cannot be interrupted from Python; a
planner that ignores its termination condition, or a pathological scene (a huge mesh), would hold
the caller forever. ``Planner`` therefore runs every request in one long-lived child process
(``python -c 'from advocc_ros.planning.worker import _worker_main; _worker_main()'``) that it reuses
across requests (imports and the robot model load once; the per-request cost is one JSON line
each way, measured ~1 ms). The parent waits for the answer with a watchdog deadline of
``time_budget_s + watchdog_margin_s``; past it, the child is killed (SIGKILL), the request is
reported as ``TIMED_OUT`` with a message saying so, and a fresh child is started on the next
request. A child that dies on its own is reported as ``CRASH``. Requests and answers are JSON
lines on the child's stdin and a private duplicate of its stdout (fd 1 itself is redirected to
stderr so that C++ output cannot corrupt the protocol); nothing is unpickled.

Why ompl 1.7.0 and how PRM* stays bounded. ompl 2.0.1's PRM/PRM* start a second C++ thread in
``solve`` that calls the Python validity checker while the first thread holds the GIL and PRM's
graph mutex, which deadlocks. The 1.7.0 Boost.Python bindings bind PRM's single-threaded
``solve``, so ``og.PRMstar`` here is OMPL's real PRM* and it honours the termination condition
(measured: a 1.0 s budget returns after ~1.0 s). The watchdog is the second line of defence.

OMPL's RNG can be seeded only before its first use in a process, so ``seed`` seeds the IK goal
sampling per request and OMPL once per worker (with the first request's seed): trials are
independent and statistically reproducible, not bit-reproducible.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import logging
import math
import os
import pathlib
import selectors
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.model.robot import RobotError, RobotModel, load_robot
from advocc_ros.model.scene import GoalRegion, Scene, SceneError, scene_from_data

log = logging.getLogger(__name__)


class PlanStatus(enum.IntEnum):
    """Outcome of a plan request; values of moveit_msgs/MoveItErrorCodes (and advocc_msgs')."""

    SUCCESS = 1
    PLANNING_FAILED = -1
    TIMED_OUT = -6
    START_STATE_IN_COLLISION = -10
    GOAL_IN_COLLISION = -12
    INVALID_GOAL_CONSTRAINTS = -16
    INVALID_ROBOT_STATE = -17
    CRASH = -29
    NO_IK_SOLUTION = -31
    INVALID_REQUEST = -101
    UNKNOWN_METHOD = -102


# OMPL geometric planners selectable by name (lower-case id -> class name in ompl.geometric).
# All of them solve the problem as set up here (goal region, default projection for KPIECE/SBL).
_PLANNER_CLASSES = (
    'RRTConnect', 'PRMstar', 'BKPIECE1', 'RRT', 'RRTstar', 'TRRT', 'LazyRRT', 'InformedRRTstar',
    'SORRTstar', 'RRTsharp', 'RRTXstatic', 'LBTRRT', 'PRM', 'LazyPRM', 'LazyPRMstar', 'KPIECE1',
    'LBKPIECE1', 'EST', 'BiEST', 'ProjEST', 'SBL', 'STRIDE', 'PDST', 'FMT', 'BFMT', 'BITstar',
    'ABITstar', 'AITstar', 'EITstar', 'SST', 'SPARS', 'SPARStwo')
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
    """Joint-space distance between validity checks along a motion [rad]. OMPL's resolution is
    set to ``motion_step_rad / max_extent`` (7.7e-4 for the Panda, extent 13.04 rad). Any
    point of the Panda moves at most 1.70 m per rad of joint motion (bound sqrt(sum r_j^2) over
    the per-joint lever arms of the collision hulls; 1.17 m/rad observed), so between two checks
    a link point travels <= 17 mm and can enter an obstacle by at most half that (8.5 mm): a path
    cannot tunnel through a 5 cm box. MoveIt's default (0.005 * extent = 65 mm of joint motion,
    up to 11 cm of link motion) could."""
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
    """Diagnostics: validity checks, goal configurations, request round trip, ..."""

    @property
    def success(self) -> bool:
        return self.status == PlanStatus.SUCCESS

    def to_data(self) -> dict:
        return {'status': int(self.status), 'message': self.message,
                'path': np.asarray(self.path, float).tolist(),
                'planning_time_s': float(self.planning_time_s), 'stats': self.stats}

    @classmethod
    def from_data(cls, data: dict, nq: int) -> 'PlanResult':
        path = np.asarray(data.get('path') or np.zeros((0, nq)), float).reshape(-1, nq)
        return cls(PlanStatus(int(data['status'])), str(data['message']), path,
                   float(data['planning_time_s']), dict(data.get('stats', {})))


def _fail(status: PlanStatus, message: str, nq: int, elapsed: float = 0.0, **stats
          ) -> PlanResult:
    return PlanResult(status, message, np.zeros((0, nq)), elapsed, stats)


def validate_request(robot: RobotModel, q_start, goal: GoalRegion, planner_id: str,
                     time_budget_s: float, config: PlanningConfig = PlanningConfig()
                     ) -> PlanResult | None:
    """An error result for a malformed request, or None; cheap, needs no collision world."""
    nq = robot.nq
    q = np.asarray(q_start, dtype=float)
    if q.shape != (nq,):
        return _fail(PlanStatus.INVALID_ROBOT_STATE,
                     f'start state: expected {nq} joint values, got shape {q.shape}', nq)
    if not np.all(np.isfinite(q)):
        return _fail(PlanStatus.INVALID_REQUEST, f'start state: non-finite values {q.tolist()}',
                     nq)
    if not robot.within_limits(q):
        bad = [robot.joint_names[i] for i in np.flatnonzero(
            (q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))]
        return _fail(PlanStatus.INVALID_ROBOT_STATE,
                     f'start state: joints {bad} outside their limits', nq)
    if planner_class_name(planner_id) is None:
        return _fail(PlanStatus.UNKNOWN_METHOD,
                     f'unknown planner {planner_id!r}; known: {sorted(PLANNERS)}', nq)
    if not (isinstance(time_budget_s, (int, float)) and math.isfinite(time_budget_s)
            and 0 < time_budget_s <= config.max_time_budget_s):
        return _fail(PlanStatus.INVALID_REQUEST, f'time budget {time_budget_s!r} s: expected '
                     f'0 < budget <= {config.max_time_budget_s}', nq)
    if not robot.model.existFrame(goal.link):
        return _fail(PlanStatus.INVALID_GOAL_CONSTRAINTS,
                     f'goal region link {goal.link!r} is not a link of the robot', nq)
    return None


class GoalSampler:
    """Collision-free configurations with FK inside a goal region, by damped-least-squares IK.

    Each attempt draws a target pose uniformly inside the region (position box x rotation-vector
    box) and a random seed configuration, then iterates DLS on the link frame until the tool
    pose enters the region (not necessarily the target: any point of the region will do).
    """

    def __init__(self, robot: RobotModel, in_collision, goal: GoalRegion,
                 rng: np.random.Generator, config: PlanningConfig = PlanningConfig()):
        self.robot, self.model = robot, robot.model
        self.data = robot.create_data()
        self.in_collision = in_collision
        self.goal, self.rng, self.config = goal, rng, config
        self.frame = robot.model.getFrameId(goal.link)
        self.T_link_tool = goal.tool_offset.to_se3()
        self.T_tool_link = self.T_link_tool.inverse()
        self.T_center = goal.center.to_se3()
        # abs: -0.0 passes '>= 0' but makes rng.uniform(-t, t) raise; huge tolerances overflow
        # its range (and mean nothing beyond a full turn or the robot's reach).
        self.tol_p = np.clip(np.abs(goal.position_tolerance_m), 0.0, 10.0)
        self.tol_r = np.clip(np.abs(goal.orientation_tolerance_rad), 0.0, math.pi)
        self.attempts = self.converged = self.colliding = 0

    def tool_pose(self, q: np.ndarray) -> pin.SE3:
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.frame] * self.T_link_tool

    def region_distance(self, q: np.ndarray) -> float:
        """0 inside the region, else the excess position [m] + orientation [rad] error."""
        p_err, r_err = self.goal.error(self.tool_pose(q))
        dp = np.maximum(np.abs(p_err) - self.tol_p, 0.0)
        dr = np.maximum(np.abs(r_err) - self.tol_r, 0.0)
        if not (np.any(dp > 1e-6) or np.any(dr > 1e-6)):
            return 0.0
        return float(np.linalg.norm(dp) + np.linalg.norm(dr))

    def attempt(self) -> np.ndarray | None:
        """One IK attempt; a valid goal configuration or None."""
        self.attempts += 1
        T_target_tool = self.T_center * pin.SE3(
            pin.exp3(self.rng.uniform(-self.tol_r, self.tol_r)),
            self.rng.uniform(-self.tol_p, self.tol_p))
        T_target = T_target_tool * self.T_tool_link
        lower, upper = self.robot.lower, self.robot.upper
        q = self.rng.uniform(lower, upper)
        eye = np.eye(6) * self.config.ik_damping
        for _ in range(self.config.ik_iterations):
            pin.framesForwardKinematics(self.model, self.data, q)
            T = self.data.oMf[self.frame]
            if self.goal.contains(T * self.T_link_tool):
                self.converged += 1
                if self.in_collision(q):
                    self.colliding += 1
                    return None
                return q
            err = pin.log6(T.actInv(T_target)).vector
            jac = pin.computeFrameJacobian(self.model, self.data, q, self.frame, pin.LOCAL)
            dq = jac.T @ np.linalg.solve(jac @ jac.T + eye, err)
            norm = np.linalg.norm(dq)
            if norm > 0.5:
                dq *= 0.5 / norm
            q = np.clip(pin.integrate(self.model, q, dq), lower, upper)
        return None

    def sample(self, n: int, deadline: float) -> list[np.ndarray]:
        """Up to ``n`` valid goal configurations found before ``deadline`` (monotonic time)."""
        out = []
        while len(out) < n and time.monotonic() < deadline:
            q = self.attempt()
            if q is not None:
                out.append(q)
        return out


# --------------------------------------------------------------------------------------------
# In-process solve (runs inside the worker; imports OMPL lazily so the parent never needs it)

_OMPL_SEEDED = False


def _ompl():
    from ompl import base as ob, geometric as og, util as ou
    return ob, og, ou


def _make_goal_class(ob):
    class RegionGoal(ob.GoalSampleableRegion):
        """OMPL goal region served from IK samples; tops itself up lazily while planning.

        ``maxSampleCount`` announces one more sample than stored while the cap and the deadline
        allow, so planners that keep asking for goals (RRTConnect grows its goal tree, PRM adds
        goal milestones) trigger one extra IK attempt per request; a failed attempt serves a
        stored goal again (harmless duplicate).
        """

        def __init__(self, si, sampler: GoalSampler, goals: list, nq: int, cap: int,
                     lazy_deadline: float):
            super().__init__(si)
            self.setThreshold(1e-9)
            self.sampler, self.goals, self.nq, self.cap = sampler, goals, nq, cap
            self.lazy_deadline, self.served = lazy_deadline, 0

        def distanceGoal(self, state):  # noqa: N802 (OMPL API)
            return self.sampler.region_distance(np.array([state[i] for i in range(self.nq)]))

        def _lazy(self) -> bool:
            return len(self.goals) < self.cap and time.monotonic() < self.lazy_deadline

        def sampleGoal(self, state):  # noqa: N802
            q = None
            if self.served < len(self.goals):
                q = self.goals[self.served]
            elif self._lazy():
                q = self.sampler.attempt()
                if q is not None:
                    self.goals.append(q)
            if q is None:
                q = self.goals[self.served % len(self.goals)]
            self.served += 1
            for i in range(self.nq):
                state[i] = float(q[i])

        def maxSampleCount(self):  # noqa: N802
            return len(self.goals) + (1 if self._lazy() else 0)

    return RegionGoal


def solve(robot: RobotModel, in_collision, q_start: np.ndarray, goal: GoalRegion,
          planner_id: str, time_budget_s: float, seed: int,
          config: PlanningConfig = PlanningConfig()) -> PlanResult:
    """Plan in this process (no watchdog: use ``Planner`` unless you are the worker).

    ``in_collision(q) -> bool`` is the scene's collision test (``CollisionWorld.in_collision``).
    """
    global _OMPL_SEEDED
    t0 = time.monotonic()
    deadline = t0 + time_budget_s
    nq = robot.nq
    error = validate_request(robot, q_start, goal, planner_id, time_budget_s, config)
    if error is not None:
        return error
    q_start = np.asarray(q_start, dtype=float)
    if in_collision(q_start):
        return _fail(PlanStatus.START_STATE_IN_COLLISION, 'start state is in collision', nq,
                     time.monotonic() - t0)
    ob, og, ou = _ompl()
    if not _OMPL_SEEDED:
        ou.RNG.setSeed(int(seed) % (2 ** 31 - 1) + 1)
        _OMPL_SEEDED = True
    rng = np.random.default_rng(int(seed) % 2 ** 64)  # int64 message seeds may be < 0
    sampler = GoalSampler(robot, in_collision, goal, rng, config)

    if sampler.region_distance(q_start) == 0.0:
        return PlanResult(PlanStatus.SUCCESS, 'start state already inside the goal region',
                          np.stack([q_start, q_start]), time.monotonic() - t0,
                          {'goal_configs': 0})
    goals = sampler.sample(config.ik_goals, t0 + config.ik_time_fraction * time_budget_s)
    ik_time = time.monotonic() - t0
    ik_stats = {'ik_attempts': sampler.attempts, 'ik_converged': sampler.converged,
                'ik_in_collision': sampler.colliding, 'ik_time_s': ik_time}
    if not goals:
        if sampler.colliding:
            return _fail(PlanStatus.GOAL_IN_COLLISION,
                         f'every goal configuration IK found ({sampler.colliding} of '
                         f'{sampler.attempts} attempts) is in collision', nq, ik_time, **ik_stats)
        return _fail(PlanStatus.NO_IK_SOLUTION,
                     f'no IK solution inside the goal region in {sampler.attempts} attempts '
                     f'({ik_time:.2f} s)', nq, ik_time, **ik_stats)

    space = ob.RealVectorStateSpace(nq)
    bounds = ob.RealVectorBounds(nq)
    for i in range(nq):
        bounds.setLow(i, float(robot.lower[i]))
        bounds.setHigh(i, float(robot.upper[i]))
    space.setBounds(bounds)
    proj = [j for j in config.projection_joints if 0 <= j < nq] or [0]
    cells, components = ou.vectorDouble(), ou.vectorUint()
    for j in proj:
        cells.append(float(robot.upper[j] - robot.lower[j]) / 20.0)
        components.append(j)
    space.registerDefaultProjection(
        ob.RealVectorOrthogonalProjectionEvaluator(space, cells, components))
    ss = og.SimpleSetup(space)
    checks = [0]

    def is_valid(state) -> bool:
        checks[0] += 1
        return not in_collision(np.array([state[i] for i in range(nq)]))

    ss.setStateValidityChecker(ob.StateValidityCheckerFn(is_valid))
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(config.motion_step_rad / space.getMaximumExtent())
    start = ob.State(space)
    for i in range(nq):
        start[i] = float(q_start[i])
    ss.setStartState(start)
    # Simplification gets what the solve leaves, at least this reserve. OMPL's simplifier checks
    # its deadline between passes, so a success can end ~0.1 s past the budget (measured).
    reserve = min(0.15 * time_budget_s, 0.5) if config.simplify else 0.0
    goal_obj = _make_goal_class(ob)(si, sampler, goals, nq, config.max_goals, deadline - reserve)
    ss.setGoal(goal_obj)
    planner = getattr(og, planner_class_name(planner_id))(si)
    ss.setPlanner(planner)
    if config.stop_at_first_solution:
        objective = ob.PathLengthOptimizationObjective(si)
        objective.setCostThreshold(ob.Cost(float('inf')))
        ss.setOptimizationObjective(objective)
    ss.setup()
    solve_time = deadline - reserve - time.monotonic()
    if solve_time <= 0:
        return _fail(PlanStatus.TIMED_OUT, 'the budget was spent sampling goal configurations',
                     nq, time.monotonic() - t0, **ik_stats)
    t_solve = time.monotonic()
    status = ss.solve(solve_time)
    solve_s = time.monotonic() - t_solve
    stats = dict(ik_stats, goal_configs=len(goals), validity_checks=checks[0],
                 solve_time_s=solve_s, planner=planner_class_name(planner_id),
                 ompl_status=status.asString())
    name = status.asString()
    if not ss.haveExactSolutionPath():
        elapsed = time.monotonic() - t0
        if name == 'Timeout' or 'Approximate' in name:
            return _fail(PlanStatus.TIMED_OUT, f'no solution within {time_budget_s:g} s '
                         f'({name.lower()})', nq, elapsed, **stats)
        return _fail(PlanStatus.PLANNING_FAILED, f'OMPL: {name}', nq, elapsed, **stats)
    if config.simplify:
        ss.simplifySolution(max(deadline - time.monotonic(), 0.01))
    path = ss.getSolutionPath()
    if config.interpolate:
        n = max(config.min_waypoints, int(math.ceil(path.length() / config.waypoint_step_rad))
                + 1)
        path.interpolate(n)
    waypoints = np.array([[path.getState(k)[i] for i in range(nq)]
                          for k in range(path.getStateCount())])
    elapsed = time.monotonic() - t0
    stats['path_length_rad'] = float(path.length())
    return PlanResult(PlanStatus.SUCCESS, f'{stats["planner"]}: solved in {elapsed:.3f} s',
                      waypoints, elapsed, stats)


# --------------------------------------------------------------------------------------------
# The worker process

def _worker_main() -> None:
    """Serve JSON-line plan requests on stdin; answers go to a private copy of stdout."""
    out = os.fdopen(os.dup(1), 'w', buffering=1)
    os.dup2(2, 1)  # C++ output on fd 1 must not corrupt the protocol
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    logging.basicConfig(level=logging.WARNING, format='planning worker: %(message)s')
    from advocc_ros.model.collision import CollisionWorld
    ob, og, ou = _ompl()
    ou.setLogLevel(ou.LOG_ERROR)
    cache: dict[str, Any] = {}

    def reply(data: dict) -> None:
        out.write(json.dumps(data) + '\n')

    reply({'ready': True, 'pid': os.getpid()})
    for line in sys.stdin:
        try:
            req = json.loads(line)
            op = req.get('op')
            if op == 'stall':  # diagnostic: a request that never answers (tests the watchdog)
                time.sleep(float(req['seconds']))
                reply({'stalled': True})
                continue
            if op != 'plan':
                raise ValueError(f'unknown op {op!r}')
            if 'scene' in req:
                scene = scene_from_data(req['scene'], 'scene')
                robot = load_robot(scene.robot)
                cache.update(key=req['scene_key'], robot=robot,
                             world=CollisionWorld(robot, scene.shapes))
            if cache.get('key') != req['scene_key']:
                raise ValueError('worker has no scene for this request')
            config = PlanningConfig(**{k: tuple(v) if isinstance(v, list) else v
                                       for k, v in req['config'].items()})
            result = solve(cache['robot'], cache['world'].in_collision,
                           np.asarray(req['q_start'], float),
                           GoalRegion.from_data(req['goal'], 'goal'), req['planner_id'],
                           float(req['time_budget_s']), int(req['seed']), config)
            reply(result.to_data())
        except Exception as exc:  # a bad request must not kill the worker
            log.exception('request failed')
            reply({'status': int(PlanStatus.PLANNING_FAILED), 'message': f'worker: {exc}',
                   'path': [], 'planning_time_s': 0.0, 'stats': {}})


class WorkerDied(RuntimeError):
    """The worker process exited or could not start."""


class _Worker:
    """One child process and its pipes."""

    def __init__(self, timeout_s: float):
        src = str(pathlib.Path(__file__).resolve().parents[1])
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(p for p in (src, env.get('PYTHONPATH')) if p)
        self.proc = subprocess.Popen(
            [sys.executable, '-c', 'from advocc_ros.planning.worker import _worker_main; '
             '_worker_main()'], stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
            close_fds=True)
        self._buf = b''
        self.scene_key: str | None = None
        try:
            hello = self.read(time.monotonic() + timeout_s)
        except BaseException:
            self.kill()
            raise
        if hello is None or not hello.get('ready'):
            self.kill()
            raise WorkerDied(f'planning worker did not start within {timeout_s:g} s')
        self.pid = int(hello['pid'])

    def send(self, data: dict) -> None:
        try:
            self.proc.stdin.write((json.dumps(data) + '\n').encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            raise WorkerDied(f'planning worker is gone ({exc})') from None

    def read(self, deadline: float) -> dict | None:
        """Next answer, or None if ``deadline`` (monotonic) passes first."""
        fd = self.proc.stdout.fileno()
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while b'\n' not in self._buf:
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    return None
                chunk = os.read(fd, 1 << 16)
                if not chunk:
                    code = self.proc.wait()
                    raise WorkerDied(f'planning worker exited with code {code}')
                self._buf += chunk
        line, self._buf = self._buf.split(b'\n', 1)
        return json.loads(line)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            try:
                pipe.close()
            except OSError:
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout_s)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.kill()


class Planner:
    """Plans in a scene with one reusable, watched worker process (see the module docstring).

    Thread-safe: concurrent ``plan`` calls are served one after the other. Use one ``Planner``
    per parallel stream of requests (each owns a process).
    """

    def __init__(self, scene: Scene, config: PlanningConfig = PlanningConfig()):
        self.config = config
        self.robot = load_robot(scene.robot)
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self.set_scene(scene)
        self.requests = 0
        self.restarts = 0

    def set_scene(self, scene: Scene) -> None:
        """Scene for the next requests (objects may change; the robot may not)."""
        if scene.robot != self.robot.spec:
            raise RobotError('a Planner plans for one robot; create another for a new robot')
        data = scene.to_data()
        key = json.dumps([scene.objects_hash(), data['robot']], sort_keys=True)
        self._scene, self._scene_data, self._scene_key = scene, data, key

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def worker_pid(self) -> int | None:
        return self._worker.pid if self._worker else None

    def start(self) -> 'Planner':
        """Start the worker now (otherwise the first request does)."""
        with self._lock:
            self._ensure_worker()
        return self

    def _ensure_worker(self) -> _Worker:
        if self._worker is None or self._worker.proc.poll() is not None:
            if self._worker is not None:
                self._worker.kill()
                self.restarts += 1
            self._worker = _Worker(self.config.worker_start_timeout_s)
            log.debug('planning worker %d started', self._worker.pid)
        return self._worker

    def _kill_worker(self) -> None:
        if self._worker is not None:
            self._worker.kill()
            self._worker = None
            self.restarts += 1

    def plan(self, q_start, goal: GoalRegion, planner_id: str = 'rrtconnect',
             time_budget_s: float | None = None, seed: int = 0) -> PlanResult:
        """Plan from ``q_start`` (nq,) to any valid configuration with FK inside ``goal``."""
        budget = self.config.time_budget_s if time_budget_s is None else time_budget_s
        error = validate_request(self.robot, q_start, goal, planner_id, budget, self.config)
        if error is not None:
            return error
        request = {'op': 'plan', 'q_start': np.asarray(q_start, float).tolist(),
                   'goal': goal.to_data(), 'planner_id': planner_id,
                   'time_budget_s': float(budget), 'seed': int(seed),
                   'config': dataclasses.asdict(self.config), 'scene_key': self._scene_key}
        with self._lock:
            self.requests += 1
            return self._call(request, budget)

    def _call(self, request: dict, budget: float) -> PlanResult:
        nq = self.robot.nq
        t0 = time.monotonic()
        try:
            worker = self._ensure_worker()
            if worker.scene_key != request['scene_key']:
                request = dict(request, scene=self._scene_data)
                worker.scene_key = request['scene_key']
            t_sent = time.monotonic()
            worker.send(request)
            answer = worker.read(t_sent + budget + self.config.watchdog_margin_s)
        except WorkerDied as exc:
            self._kill_worker()
            log.error('%s', exc)
            return _fail(PlanStatus.CRASH, str(exc), nq, time.monotonic() - t0)
        round_trip = time.monotonic() - t_sent
        if answer is None:
            self._kill_worker()
            msg = (f'watchdog: no answer within budget {budget:g} s + margin '
                   f'{self.config.watchdog_margin_s:g} s; worker killed')
            log.error('%s', msg)
            return _fail(PlanStatus.TIMED_OUT, msg, nq, round_trip, watchdog=True)
        if 'status' not in answer:
            return _fail(PlanStatus.PLANNING_FAILED, f'unexpected worker answer {answer}', nq)
        result = PlanResult.from_data(answer, nq)
        result.stats['round_trip_s'] = round_trip
        result.stats['overhead_s'] = round_trip - result.planning_time_s
        return result

    def _stall(self, seconds: float, watchdog_s: float) -> PlanResult:
        """Diagnostic: send a request that holds the worker ``seconds`` (tests the watchdog)."""
        with self._lock:
            worker = self._ensure_worker()
            worker.send({'op': 'stall', 'seconds': seconds})
            t0 = time.monotonic()
            answer = worker.read(t0 + watchdog_s)
            if answer is None:
                self._kill_worker()
                return _fail(PlanStatus.TIMED_OUT, 'watchdog: worker killed', self.robot.nq,
                             time.monotonic() - t0, watchdog=True)
            return _fail(PlanStatus.SUCCESS, 'stall answered', self.robot.nq,
                         time.monotonic() - t0)

    def close(self) -> None:
        with self._lock:
            if self._worker is not None:
                self._worker.close()
                self._worker = None

    def __enter__(self) -> 'Planner':
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        worker = getattr(self, '_worker', None)
        if worker is not None:
            worker.kill()


def start_configuration(scene: Scene, robot: RobotModel) -> np.ndarray:
    """``q_init`` of a scene, or a clear error when the scene has none."""
    if scene.start is None:
        raise SceneError(f'scene {scene.name!r} has no start configuration')
    return robot.q_from_names(list(scene.start), list(scene.start.values()),
                              f'{scene.name}.start')
