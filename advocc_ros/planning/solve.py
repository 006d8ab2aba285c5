"""One OMPL solve to a goal region, in-process (it runs inside the planning worker).

OMPL is imported lazily, so the parent process never needs it. The same code runs on OMPL 1.7
(Boost.Python, our venv: RRTConnect, PRM*, BKPIECE1) and on OMPL 2.0 (nanobind, ``.venv-ompl2``:
the ``aorrtc`` and ``rrtconnect2`` victims); the three places where their Python APIs differ
(the validity checker, a new state, the projection's vectors) are :func:`_legacy_api`'s.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import GoalSampler
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import JOINT_TOLERANCE_RAD, GoalRegion
from advocc_ros.planning.motion import make_motion_validator
from advocc_ros.planning.types import (PlanningConfig, PlanResult, PlanStatus, failed,
                                       planner_class_name, validate_request)

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# In-process solve (runs inside the worker; imports OMPL lazily so the parent never needs it)

_OMPL_SEEDED = False


def ompl_modules():
    """OMPL's ``base``, ``geometric`` and ``util`` modules, imported on first use (the parent
    process never needs OMPL)."""
    from ompl import base as ob, geometric as og, util as ou
    return ob, og, ou


def ompl_version() -> str | None:
    """The version of the OMPL this interpreter imports (1.7.0 in our venv, 2.0.1 in
    ``.venv-ompl2``): its distribution's, since the ``ompl`` module carries no version
    attribute; None for an OMPL installed without distribution metadata."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version('ompl')
    except PackageNotFoundError:
        return None


def _legacy_api(ob) -> bool:
    """Whether ``ob`` is OMPL 1.x's Boost.Python ``ompl.base`` (a checker is wrapped in
    ``StateValidityCheckerFn``, states are ``ob.State(space)``, vectors are ``ou.vector*``);
    OMPL 2.0's nanobind bindings take a callable, ``space.allocState()`` and lists."""
    return hasattr(ob, 'StateValidityCheckerFn')


def _make_goal_class(ob):
    class RegionGoal(ob.GoalSampleableRegion):
        """OMPL goal region served from IK samples; tops itself up lazily while planning.

        ``maxSampleCount`` announces one more sample than stored while the cap and the deadline
        allow, so planners that keep asking for goals (RRTConnect grows its goal tree, PRM adds
        goal milestones) trigger one extra IK attempt per request; a failed attempt serves a
        stored goal again (harmless duplicate).

        ``first_pair_t`` is the monotonic time of the first ``isStartGoalPairValid`` call: the
        moment an exact solution first exists. RRTConnect and BKPIECE1 call it when their trees
        connect, PRM/PRM* when a start and a goal milestone join one component (measured: with
        ``stop_at_first_solution`` PRM* returns within a millisecond of it), so optimizing
        planners that run to the budget still report when they first solved the task.
        """

        def __init__(self, si, sampler: GoalSampler, goals: list, nq: int, cap: int,
                     lazy_deadline: float, distance):
            super().__init__(si)
            self.setThreshold(1e-9)
            self.sampler, self.goals, self.nq, self.cap = sampler, goals, nq, cap
            self.distance = distance
            self.lazy_deadline, self.served = lazy_deadline, 0
            self.first_pair_t: float | None = None

        def distanceGoal(self, state):  # noqa: N802 (OMPL API)
            return self.distance(np.array([state[i] for i in range(self.nq)]))

        def isStartGoalPairValid(self, start, goal):  # noqa: N802
            if self.first_pair_t is None:
                self.first_pair_t = time.monotonic()
            return True  # OMPL's default: every pair is valid

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


def goal_distance(robot: RobotModel, goal: GoalRegion, sampler: GoalSampler):
    """The distance to the goal that OMPL's goal test reads (0: reached): the region's excess
    pose error, or for a ``joint`` goal the joint-space distance beyond
    ``JOINT_TOLERANCE_RAD``."""
    if not goal.is_joint:
        return sampler.region_distance
    q_goal = goal.configuration(robot.joint_names)

    def distance(q: np.ndarray) -> float:
        d = float(np.linalg.norm(q - q_goal))
        return 0.0 if d <= JOINT_TOLERANCE_RAD else d
    return distance


def joint_space(ob, robot: RobotModel):
    """OMPL's state space over the arm joints, bounded by the joint limits."""
    space = ob.RealVectorStateSpace(robot.nq)
    bounds = ob.RealVectorBounds(robot.nq)
    for i in range(robot.nq):
        bounds.setLow(i, float(robot.lower[i]))
        bounds.setHigh(i, float(robot.upper[i]))
    space.setBounds(bounds)
    return space


def solve(robot: RobotModel, world: CollisionWorld, q_start: np.ndarray, goal: GoalRegion,
          planner_id: str, time_budget_s: float, seed: int,
          config: PlanningConfig = PlanningConfig(), goal_configs=None) -> PlanResult:
    """Plan in this process (no watchdog: use ``Planner`` unless you are the worker).

    ``world`` is the scene's collision model: its ``in_collision`` checks single states and its
    ``first_collision`` the states along a motion. A success's ``stats['first_solution_s']`` is
    the time from the request to the first exact solution (before simplification).
    ``goal_configs`` (K, nq): plan to this fixed goal list (the victims' like-for-like option:
    no IK inside the budget, no lazy goal sampling) instead of sampling the region. A goal in
    the ``joint`` form is its configuration alone: the list is that configuration, and a state
    reaches it within ``JOINT_TOLERANCE_RAD``.
    """
    t0 = time.monotonic()
    nq = robot.nq
    error = validate_request(robot, q_start, goal, planner_id, time_budget_s, config)
    if error is not None:
        return error
    q_start = np.asarray(q_start, dtype=float)
    if world.in_collision(q_start):
        return failed(PlanStatus.START_STATE_IN_COLLISION, 'start state is in collision', nq,
                      time.monotonic() - t0)
    ob, og, ou = ompl_modules()
    if not hasattr(og, planner_class_name(planner_id)):
        return failed(PlanStatus.UNKNOWN_METHOD, f'{planner_class_name(planner_id)} is not in '
                      f'this OMPL (ompl {ompl_version()}): it is an OMPL 2 planner, planned by '
                      'the victim of that name (advocc_ros.planning.victims.ompl2)', nq)
    _seed_ompl(ou, seed)
    rng = np.random.default_rng(int(seed) % 2 ** 64)  # int64 message seeds may be < 0
    sampler = GoalSampler(robot, world.in_collision, goal, rng, config)
    if goal.is_joint:
        goal_configs = goal.configuration(robot.joint_names)[None]
    if goal_distance(robot, goal, sampler)(q_start) == 0.0:
        elapsed = time.monotonic() - t0
        return PlanResult(PlanStatus.SUCCESS, 'start state already inside the goal region',
                          np.stack([q_start, q_start]), elapsed,
                          {'goal_configs': 0, 'first_solution_s': elapsed})
    if goal_configs is not None:
        return _solve_to_list(robot, world, q_start, planner_id, time_budget_s, config, t0,
                              sampler, goal_configs)
    goals = sampler.sample(config.ik_goals, t0 + config.ik_time_fraction * time_budget_s)
    ik_stats = {'ik_attempts': sampler.attempts, 'ik_converged': sampler.converged,
                'ik_in_collision': sampler.colliding, 'ik_time_s': time.monotonic() - t0}
    if not goals:
        return _no_goal(sampler, nq, ik_stats)
    return _solve_to(robot, world, q_start, planner_id, time_budget_s, config, t0, sampler,
                     goals, config.max_goals, ik_stats)


def _solve_to_list(robot, world, q_start, planner_id, time_budget_s, config, t0, sampler,
                   goal_configs) -> PlanResult:
    """Solve to a given goal list; goals in collision in ``world`` are dropped first."""
    nq = robot.nq
    Q = np.asarray(goal_configs, dtype=float).reshape(-1, nq)
    goals = list(Q[~world.collisions_batch(Q)]) if len(Q) else []
    stats = {'goal_list': len(Q), 'goal_list_valid': len(goals)}
    if not goals:
        return failed(PlanStatus.GOAL_STATE_INVALID, f'none of the {len(Q)} given goal '
                      'configurations is valid', nq, time.monotonic() - t0, **stats)
    return _solve_to(robot, world, q_start, planner_id, time_budget_s, config, t0, sampler,
                     goals, len(goals), stats)


def _solve_to(robot, world, q_start, planner_id, time_budget_s, config, t0, sampler, goals,
              cap, ik_stats) -> PlanResult:
    """OMPL's solve from ``q_start`` to ``goals`` (topped up by IK up to ``cap``)."""
    ob, og, ou = ompl_modules()
    nq = robot.nq
    # Simplification gets what the solve leaves, at least this reserve. OMPL's simplifier checks
    # its deadline between passes, so a success can end ~0.1 s past the budget (measured).
    reserve = min(0.15 * time_budget_s, 0.5) if config.simplify else 0.0
    solve_deadline = t0 + time_budget_s - reserve
    checks = _CheckCounter()
    ss = _simple_setup(ob, og, ou, robot, world, q_start, planner_id, config, checks)
    checks.problem = ss.getProblemDefinition()
    goal_obj = _make_goal_class(ob)(ss.getSpaceInformation(), sampler, goals, nq, cap,
                                    solve_deadline, goal_distance(robot, sampler.goal, sampler))
    ss.setGoal(goal_obj)
    ss.setup()
    solve_time = solve_deadline - time.monotonic()
    if solve_time <= 0:
        return failed(PlanStatus.TIMED_OUT, 'the budget was spent sampling goal configurations',
                      nq, time.monotonic() - t0, **ik_stats)
    t_solve = time.monotonic()
    status = ss.solve(solve_time)
    stats = dict(ik_stats, goal_configs=len(goals), validity_checks=checks[0],
                 solve_time_s=time.monotonic() - t_solve,
                 planner=planner_class_name(planner_id), ompl_status=status.asString())
    if not ss.haveExactSolutionPath():
        return _no_solution(status.asString(), time_budget_s, nq, time.monotonic() - t0, stats)
    broken = _not_a_solution(ss, q_start, goal_obj, nq)
    if broken:
        # OMPL 2.0.1's AORRTC: when its first connection reaches the start tree's root, its own
        # simplification leaves a zero-length path at a goal and it answers INVALID_GOAL.
        return failed(PlanStatus.PLANNING_FAILED, f'{stats["planner"]}: {broken} (OMPL status: '
                      f'{status.asString()})', nq, time.monotonic() - t0, **stats)
    first = goal_obj.first_pair_t or checks.first_exact_t  # AORRTC never asks for the pair
    stats['first_solution_s'] = (first if first is not None else time.monotonic()) - t0
    return _solution(ss, world, t0, t0 + time_budget_s, config, stats)


def _not_a_solution(ss, q_start: np.ndarray, goal_obj, nq: int) -> str:
    """Why the exact solution OMPL holds is not a path of the task ('' if it is one): it must
    run from the start state to a state the goal accepts."""
    path = ss.getSolutionPath()
    n = path.getStateCount()
    if n < 1:
        return 'its solution has no state'
    first = np.array([path.getState(0)[i] for i in range(nq)])
    if not np.allclose(first, q_start, atol=1e-9):
        return (f'its solution does not start at the start state (off by '
                f'{np.abs(first - q_start).max():.3g} rad; {n} states, length '
                f'{path.length():.3g} rad)')
    if not goal_obj.isSatisfied(path.getState(n - 1)):
        return 'its solution does not end in the goal'
    return ''


class _CheckCounter(list):
    """``[states checked]``, counted by the validity checker and the motion validator
    (``checks[0] += n``), which also notes ``first_exact_t``: the monotonic time at which
    ``problem`` (OMPL's problem definition) was first seen holding an exact solution, polled
    every ``POLL`` states. It is the first-solution mark of planners that never call
    ``isStartGoalPairValid`` (AORRTC), to within ``POLL`` checks (~1 ms)."""

    POLL = 64

    def __init__(self):
        super().__init__([0])
        self.problem = None
        self.first_exact_t: float | None = None
        self._next_poll = self.POLL

    def __setitem__(self, index, value):
        super().__setitem__(index, value)
        if value >= self._next_poll and self.first_exact_t is None and self.problem is not None:
            self._next_poll = value + self.POLL
            if self.problem.hasExactSolution():
                self.first_exact_t = time.monotonic()


def _seed_ompl(ou, seed: int) -> None:
    """Seed OMPL's RNG; only the first call in a process has an effect (OMPL's rule)."""
    global _OMPL_SEEDED
    if not _OMPL_SEEDED:
        ou.RNG.setSeed(int(seed) % (2 ** 31 - 1) + 1)
        _OMPL_SEEDED = True


def _no_goal(sampler: GoalSampler, nq: int, ik_stats: dict) -> PlanResult:
    """The failure when IK found no collision-free goal configuration in its share of time."""
    ik_time = ik_stats['ik_time_s']
    if sampler.colliding:
        return failed(PlanStatus.GOAL_IN_COLLISION,
                      f'every goal configuration IK found ({sampler.colliding} of '
                      f'{sampler.attempts} attempts) is in collision', nq, ik_time, **ik_stats)
    return failed(PlanStatus.NO_IK_SOLUTION,
                  f'no IK solution inside the goal region in {sampler.attempts} attempts '
                  f'({ik_time:.2f} s)', nq, ik_time, **ik_stats)


def _simple_setup(ob, og, ou, robot: RobotModel, world: CollisionWorld, q_start: np.ndarray,
                  planner_id: str, config: PlanningConfig, checks: list):
    """OMPL's SimpleSetup: space with the KPIECE/SBL projection, validity and motion checks
    (counted in ``checks[0]``), start state, planner and objective; the goal is set by the
    caller."""
    nq = robot.nq
    space = joint_space(ob, robot)
    proj = [j for j in config.projection_joints if 0 <= j < nq] or [0]
    legacy = _legacy_api(ob)
    cells, components = (ou.vectorDouble(), ou.vectorUint()) if legacy else ([], [])
    for j in proj:
        cells.append(float(robot.upper[j] - robot.lower[j]) / 20.0)
        components.append(j)
    space.registerDefaultProjection(
        ob.RealVectorOrthogonalProjectionEvaluator(space, cells, components))
    ss = og.SimpleSetup(space)

    def is_valid(state) -> bool:
        checks[0] += 1
        return not world.in_collision(np.array([state[i] for i in range(nq)]))

    ss.setStateValidityChecker(ob.StateValidityCheckerFn(is_valid) if legacy else is_valid)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(config.motion_step_rad / space.getMaximumExtent())
    si.setMotionValidator(make_motion_validator(ob, si, space, world, nq, checks))
    start = ob.State(space) if legacy else space.allocState()
    for i in range(nq):
        start[i] = float(q_start[i])
    ss.setStartState(start)
    ss.setPlanner(getattr(og, planner_class_name(planner_id))(si))
    if config.stop_at_first_solution:
        objective = ob.PathLengthOptimizationObjective(si)
        objective.setCostThreshold(ob.Cost(float('inf')))
        ss.setOptimizationObjective(objective)
    return ss


def _no_solution(name: str, time_budget_s: float, nq: int, elapsed: float, stats: dict
                 ) -> PlanResult:
    """The failure when OMPL returned without an exact solution (``name``: its status)."""
    if name == 'Timeout' or 'Approximate' in name:
        return failed(PlanStatus.TIMED_OUT, f'no solution within {time_budget_s:g} s '
                      f'({name.lower()})', nq, elapsed, **stats)
    return failed(PlanStatus.PLANNING_FAILED, f'OMPL: {name}', nq, elapsed, **stats)


def _solution(ss, world: CollisionWorld, t0: float, deadline: float, config: PlanningConfig,
              stats: dict) -> PlanResult:
    """The solution simplified and interpolated like MoveIt's defaults, then validated like
    MoveIt's ``ValidateSolution`` response adapter: a waypoint in collision (interpolation put
    it between two states the motion check passed) makes the answer ``INVALID_MOTION_PLAN``."""
    nq = world.robot.nq
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
    colliding = np.flatnonzero(world.collisions_batch(waypoints))
    if len(colliding):
        return failed(PlanStatus.INVALID_MOTION_PLAN, f'{stats["planner"]}: waypoint '
                      f'{colliding[0]} of the {len(waypoints)} of its solution is in collision '
                      '(between two states its motion check passed)', nq, elapsed, **stats)
    return PlanResult(PlanStatus.SUCCESS, f'{stats["planner"]}: solved in {elapsed:.3f} s',
                      waypoints, elapsed, stats)
