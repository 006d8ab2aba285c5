"""TrajOpt (Tesseract) as an optimization-based victim: goal configurations in, a path out.

TrajOpt (Schulman et al.; ROS-Industrial's Tesseract, PyPI ``tesseract-robotics`` 0.5.1) is a
sequential convex optimizer over a fixed number of joint-space waypoints with signed-distance
collision constraints. Set up as its users would (Tesseract's own examples and defaults, tuned
for these scenes only by the number of waypoints and the margins below):

- the goal is a joint configuration: one of K collision-free configurations of the goal region
  from our seeded goal sampler, re-checked in Tesseract's own collision model (Bullet, convex
  hulls). No valid goal configuration is its own outcome (``NO_VALID_GOAL``), never a planner
  failure;
- restarts: first a straight-line initial guess to each goal configuration, the least blocked
  first (share of ``probe_states`` states of the line in collision, then joint distance: on
  table_under_pick, 8 of 8 first attempts succeeded so ordered, 5 of 8 nearest-first, and in
  about half the time); then, until the budget ends, a guess through a via-point (the
  midpoint of a random goal's straight line, perturbed by N(0, ``via_std_rad``) per joint;
  the least blocked of ``via_candidates``);
- collision: a hard constraint at ``collision_margin_m`` with a cost out to ``cost_margin_m``
  (Tesseract's default margins and weights), evaluated on the motion between waypoints
  (``LVS_CONTINUOUS``: the swept convex hulls of pieces of at most ``lvs_step_rad``), not only
  at the waypoints (Tesseract's default ``DISCRETE``), so that a converged path is
  collision-free between waypoints;
- the victim's own post-check (Tesseract's discrete checker along the path every
  ``VictimConfig.check_step_rad``, what Tesseract's task composer runs after TrajOpt) rejects
  an attempt whose path collides anyway, and the restarts go on.

Every accepted path is re-validated by our exact checker at the same step. A path that collides
there but passed Tesseract's own check (both use convex hulls here: 2,000 random Panda
configurations got the same verdicts in both models on table_pick and cage) is reported as
``MODEL_MISMATCH``, never counted as a success. A solution that arrives after
the budget is a ``TIMEOUT``: TrajOpt's SQP cannot be interrupted from Python, so an attempt
started before the deadline may end after it (the worker's watchdog bounds that).
"""

from __future__ import annotations

import dataclasses
import enum
import time

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.shapes import Shape
from advocc_ros.planning.types import PlanResult, PlanStatus
from advocc_ros.planning.victims.base import (VictimConfig, densify, first_collision_along,
                                              path_length_rad)
from advocc_ros.planning.victims.tesseract_env import MANIPULATOR, TesseractWorld

PROFILE = 'DEFAULT'
NAMESPACE = 'TrajOptMotionPlannerTask'


class OptimOutcome(enum.Enum):
    """How a TrajOpt plan ended (``PlanResult.stats['outcome']``)."""

    SUCCESS = 'success'
    LOCAL_MINIMUM = 'local_minimum'
    """Every attempt stopped infeasible: the SQP's penalty or iteration limit (a local minimum
    of the constraint violation, typically a guess through an obstacle it cannot leave)."""
    SOLVER_FAILURE = 'solver_failure'
    """TrajOpt or its QP solver failed for another reason (an error, a bad problem)."""
    PATH_IN_COLLISION = 'path_in_collision'
    """TrajOpt converged but the path collides in Tesseract's own dense check (the attempt is
    rejected and restarts go on; the plan's outcome if every attempt ended so)."""
    MODEL_MISMATCH = 'model_mismatch'
    """An accepted path (free in Tesseract's dense check) collides in our exact checker."""
    TIMEOUT = 'timeout'
    """No attempt finished within the budget, or the first success came after it. (When the
    budget ends after failed attempts, their most frequent failure is the outcome.)"""
    NO_VALID_GOAL = 'no_valid_goal'
    INVALID_START = 'invalid_start'


_PLAN_STATUS = {
    OptimOutcome.SUCCESS: PlanStatus.SUCCESS,
    OptimOutcome.LOCAL_MINIMUM: PlanStatus.PLANNING_FAILED,
    OptimOutcome.SOLVER_FAILURE: PlanStatus.PLANNING_FAILED,
    OptimOutcome.PATH_IN_COLLISION: PlanStatus.INVALID_MOTION_PLAN,
    OptimOutcome.MODEL_MISMATCH: PlanStatus.MODEL_MISMATCH,
    OptimOutcome.TIMEOUT: PlanStatus.TIMED_OUT,
    OptimOutcome.NO_VALID_GOAL: PlanStatus.GOAL_STATE_INVALID,
    OptimOutcome.INVALID_START: PlanStatus.START_STATE_IN_COLLISION,
}


EVALUATORS = ('lvs_discrete', 'lvs_continuous', 'continuous', 'discrete')


@dataclasses.dataclass(frozen=True)
class TrajOptConfig:
    """How the TrajOpt victim is set up (see the module docstring for why)."""

    waypoints: int = 20
    """Waypoints of the optimized path, start and goal included (TrajOpt's examples: 10-50;
    on table_under_pick 20 solved as many straight-line attempts as 30, ~1.5x faster)."""
    collision_margin_m: float = 0.01
    """Distance every link must keep from obstacles and other links (hard constraint) [m]."""
    collision_buffer_m: float = 0.02
    """Distance beyond the margin at which collision terms are already linearized [m]
    (Tesseract's default 0.05 was no better here and ~20 % slower)."""
    cost_margin_m: float = 0.025
    """Collision cost pushes links out to this distance (soft) [m]."""
    collision_coeff: float = 20.0
    """Weight of the collision constraint and cost terms (TrajOpt's examples: 10-20)."""
    evaluator: str = 'lvs_continuous'
    """Collision terms between waypoints (``tesseract_collision.CollisionEvaluatorType``):
    ``lvs_discrete`` (discrete checks every ``lvs_step_rad``), ``lvs_continuous`` (swept
    convex hulls over ``lvs_step_rad`` pieces), ``continuous`` (one swept hull per segment) or
    ``discrete`` (at the waypoints only: Tesseract's default, which lets a converged path cut
    corners through an obstacle between waypoints)."""
    lvs_step_rad: float = 0.05
    """Joint-space step of the swept-state collision terms between waypoints [rad]."""
    via_std_rad: float = 0.6
    """Standard deviation of a restart's via-point perturbation, per joint [rad]."""
    via_candidates: int = 8
    """Random via-points drawn per restart; the one whose guess collides least is used."""
    probe_states: int = 20
    """States of a guess checked to rank guesses by their share of colliding states (~3 ms
    per guess of 20 states; ranking 32 straight lines took ~0.1 s on a loaded machine)."""
    endpoint_tol_rad: float = 2e-3
    """A converged path must start and end this close to its start and goal (per joint); its
    ends are then set to them exactly [rad]."""
    clearance_cap_m: float = 0.1
    """Clearances beyond this are reported as this (distance queries stop there) [m]."""
    max_attempts: int = 200
    """Cap on restarts per plan (the budget usually ends them first)."""

    def __post_init__(self):
        if self.evaluator not in EVALUATORS:
            raise ValueError(f'TrajOpt parameter evaluator={self.evaluator!r}: expected one of '
                             f'{list(EVALUATORS)}')
        for f in dataclasses.fields(self):
            if f.name == 'evaluator':
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not np.isfinite(value) or value <= 0:
                raise ValueError(f'TrajOpt parameter {f.name}={value!r}: expected > 0')
        for name in ('waypoints', 'via_candidates', 'probe_states', 'max_attempts'):
            if not isinstance(getattr(self, name), int):
                raise ValueError(f'TrajOpt parameter {name}={getattr(self, name)!r}: expected an '
                                 'integer')
        if self.waypoints < 3:
            raise ValueError(f'TrajOpt parameter waypoints={self.waypoints!r}: expected an '
                             'integer >= 3')


def initial_guess(q_start: np.ndarray, q_goal: np.ndarray, via: np.ndarray | None,
                  n: int) -> np.ndarray:
    """TrajOpt's (n, nq) initial guess: the straight line, or two straight lines through
    ``via``."""
    if via is None:
        return q_start + (q_goal - q_start) * np.linspace(0, 1, n)[:, None]
    half = n // 2
    first = q_start + (via - q_start) * np.linspace(0, 1, half + 1)[:, None]
    second = via + (q_goal - via) * np.linspace(0, 1, n - half)[:, None]
    return np.concatenate([first[:-1], second])


def snap_ends(path: np.ndarray, q_start: np.ndarray, q_goal: np.ndarray, tol_rad: float
              ) -> np.ndarray | None:
    """``path`` with its ends set exactly to the start and the goal, or None when TrajOpt left
    them further than ``tol_rad`` away. TrajOpt keeps joints 1e-3 rad inside their limits, so a
    goal configuration at a limit (our sampler clips to the limits) ends 1e-3 rad short: seen
    in 3 of 20 bookshelf trials."""
    if len(path) < 2 or np.abs(path[0] - q_start).max() > tol_rad \
            or np.abs(path[-1] - q_goal).max() > tol_rad:
        return None
    path = path.copy()
    path[0], path[-1] = q_start, q_goal
    return path


class TrajOptSolver:
    """One robot's TrajOpt set-up; ``plan`` solves one task (runs in-process, unbounded by
    wall-clock inside an attempt: use ``TrajOptVictim`` for a watched worker process)."""

    def __init__(self, robot: RobotModel, config: TrajOptConfig = TrajOptConfig(),
                 check_step_rad: float = VictimConfig.check_step_rad):
        self.robot = robot
        self.config = config
        self.check_step_rad = check_step_rad
        """Step of the dense re-validation of a path, Tesseract's and ours [rad]."""
        self.tesseract = TesseractWorld(robot)
        self.ours = CollisionWorld(robot, [])
        self._shapes_key = None

    def set_objects(self, shapes: list[Shape]) -> None:
        key = [s.fingerprint() for s in shapes]
        if key != self._shapes_key:
            self.tesseract.set_objects(shapes)
            self.ours = CollisionWorld(self.robot, shapes)
            self._shapes_key = key

    # ---- one attempt ----------------------------------------------------------------------

    def _program(self, guess: np.ndarray):
        from tesseract_robotics import tesseract_command_language as tl
        from tesseract_robotics.tesseract_common import ManipulatorInfo

        manip = ManipulatorInfo()
        manip.manipulator = MANIPULATOR
        manip.tcp_frame = self.robot.spec.ee_link
        manip.working_frame = self.tesseract.root
        program = tl.CompositeInstruction(PROFILE)
        program.setManipulatorInfo(manip)
        names = list(self.robot.joint_names)
        for i, q in enumerate(guess):
            waypoint = tl.JointWaypoint(names, np.asarray(q, float))
            # Intermediate waypoints are only the initial guess; the ends are constraints.
            waypoint.setIsConstrained(i in (0, len(guess) - 1))
            move = tl.MoveInstruction(tl.JointWaypointPoly_wrap_JointWaypoint(waypoint),
                                      tl.MoveInstructionType_FREESPACE, PROFILE)
            program.appendMoveInstruction(tl.MoveInstructionPoly_wrap_MoveInstruction(move))
        return program

    def _profiles(self):
        from tesseract_robotics import tesseract_collision as tc
        from tesseract_robotics.tesseract_command_language import ProfileDictionary
        from tesseract_robotics import tesseract_motion_planners_trajopt as tt

        c = self.config
        composite = tt.TrajOptDefaultCompositeProfile()
        composite.longest_valid_segment_length = c.lvs_step_rad
        for term, margin in ((composite.collision_constraint_config, c.collision_margin_m),
                             (composite.collision_cost_config, c.cost_margin_m)):
            term.enabled = True
            term.type = getattr(tc, f'CollisionEvaluatorType_{c.evaluator.upper()}')
            term.safety_margin = margin
            term.safety_margin_buffer = c.collision_buffer_m
            term.coeff = c.collision_coeff
        profiles = ProfileDictionary()
        profiles.addProfile(NAMESPACE, PROFILE, tt.TrajOptDefaultPlanProfile())
        profiles.addProfile(NAMESPACE, PROFILE, composite)
        return profiles, composite

    def _solve(self, guess: np.ndarray) -> tuple[np.ndarray | None, str]:
        """(path (N, nq) or None, TrajOpt's message)."""
        from tesseract_robotics import tesseract_command_language as tl
        from tesseract_robotics.tesseract_motion_planners import PlannerRequest
        from tesseract_robotics.tesseract_motion_planners_trajopt import TrajOptMotionPlanner

        program = self._program(guess)
        profiles, composite = self._profiles()
        request = PlannerRequest()
        request.instructions = program
        request.env = self.tesseract.env
        request.profiles = profiles
        planner = TrajOptMotionPlanner(NAMESPACE)
        response = planner.solve(request)
        message = str(response.message)
        if not response.successful:
            return None, message
        results = response.results  # keep every SWIG temporary referenced (module docs)
        flat = results.flatten()
        path = []
        for instruction in flat:
            move = tl.InstructionPoly_as_MoveInstructionPoly(instruction)
            waypoint = move.getWaypoint()
            if waypoint.isStateWaypoint():
                state = tl.WaypointPoly_as_StateWaypointPoly(waypoint)
            else:
                state = tl.WaypointPoly_as_JointWaypointPoly(waypoint)
            path.append(np.array(state.getPosition(), float).ravel())
        del composite
        return np.array(path), message

    # ---- one plan -------------------------------------------------------------------------

    def _collision_fraction(self, guess: np.ndarray) -> float:
        """Share of ``probe_states`` states of a guess that collide in Tesseract's model."""
        idx = np.linspace(0, len(guess) - 1, self.config.probe_states).round().astype(int)
        return float(self.tesseract.collisions(guess[idx]).mean())

    def _attempts(self, q_start: np.ndarray, goals: np.ndarray, rng: np.random.Generator):
        """(goal index, via-point or None) of each attempt, in order (module docstring)."""
        n = self.config.waypoints
        distance = np.linalg.norm(goals - q_start, axis=1)
        blocked = np.array([self._collision_fraction(initial_guess(q_start, g, None, n))
                            for g in goals])
        for k in np.lexsort((distance, blocked)):
            yield int(k), None
        while True:
            k = int(rng.integers(len(goals)))
            vias = np.clip((q_start + goals[k]) / 2 + rng.normal(
                0.0, self.config.via_std_rad, (self.config.via_candidates, self.robot.nq)),
                self.robot.lower, self.robot.upper)
            yield k, min(vias, key=lambda v: self._collision_fraction(
                initial_guess(q_start, goals[k], v, n)))

    def plan(self, q_start, goal_configs, budget_s: float, seed: int) -> PlanResult:
        """Plan from ``q_start`` (nq,) to any of ``goal_configs`` (K, nq) within ``budget_s``."""
        t0 = time.monotonic()
        deadline = t0 + budget_s
        nq = self.robot.nq
        q_start = self.robot.check_q(q_start, 'start')
        goals = np.asarray(goal_configs, float).reshape(-1, nq)
        within = np.all((goals >= self.robot.lower - 1e-9) & (goals <= self.robot.upper + 1e-9),
                        axis=1)
        valid = within & ~self.tesseract.collisions(goals) if len(goals) else within
        stats: dict = {'goal_configs': len(goals), 'goal_configs_valid': int(valid.sum()),
                       'attempts': []}
        if self.ours.in_collision(q_start) or self.tesseract.collisions(q_start[None])[0]:
            return _result(OptimOutcome.INVALID_START, 'start configuration in collision',
                           nq, t0, stats)
        if not valid.any():
            return _result(OptimOutcome.NO_VALID_GOAL, f'none of {len(goals)} goal '
                           'configurations is valid in Tesseract\'s model', nq, t0, stats)
        goals = goals[valid]
        rng = np.random.default_rng(seed)
        for goal_index, via in self._attempts(q_start, goals, rng):
            if time.monotonic() >= deadline or len(stats['attempts']) >= self.config.max_attempts:
                break
            kind, path = self._attempt(q_start, goals[goal_index], via, stats)
            if kind is OptimOutcome.SUCCESS:
                return self._accept(path, t0, budget_s, stats)
            if kind is OptimOutcome.MODEL_MISMATCH:
                return _result(kind, 'TrajOpt\'s path passed Tesseract\'s dense check but '
                               f'collides in ours (checked every {self.check_step_rad:g} rad)',
                               nq, t0, stats)
        return self._give_up(t0, stats)

    def _attempt(self, q_start, q_goal, via, stats) -> tuple[OptimOutcome, np.ndarray | None]:
        t = time.monotonic()
        guess = initial_guess(q_start, q_goal, via, self.config.waypoints)
        try:
            path, message = self._solve(guess)
        except Exception as exc:  # a SWIG/C++ error in one attempt: try the next one
            path, message = None, f'{type(exc).__name__}: {exc}'
        if path is not None:
            path = snap_ends(path, q_start, q_goal, self.config.endpoint_tol_rad)
            if path is None:
                message = f'the path ends more than {self.config.endpoint_tol_rad:g} rad ' \
                    'from its start or goal'
        if path is None:
            kind = (OptimOutcome.LOCAL_MINIMUM if 'LIMIT' in message or 'INFEASIBLE'
                    in message.upper() else OptimOutcome.SOLVER_FAILURE)
        else:
            if self.tesseract.collisions(densify(path, self.check_step_rad)).any():
                kind = OptimOutcome.PATH_IN_COLLISION
            elif first_collision_along(self.ours, path, self.check_step_rad) >= 0:
                kind = OptimOutcome.MODEL_MISMATCH
            else:
                kind = OptimOutcome.SUCCESS
        stats['attempts'].append({'guess': 'straight' if via is None else 'via',
                                  'outcome': kind.value, 'message': message[:120],
                                  'time_s': time.monotonic() - t})
        return kind, path

    def _accept(self, path: np.ndarray, t0: float, budget_s: float, stats: dict) -> PlanResult:
        first = time.monotonic() - t0
        stats['first_solution_s'] = first
        if first > budget_s:
            return _result(OptimOutcome.TIMEOUT, f'first solution after {first:.2f} s, past '
                           f'the {budget_s:g} s budget', self.robot.nq, t0, stats)
        dense = densify(path, self.check_step_rad)
        stats['path_length_rad'] = path_length_rad(path)
        stats['min_clearance_m'] = float(
            self.ours.scene_clearances(dense, self.config.clearance_cap_m).min())
        result = _result(OptimOutcome.SUCCESS, f'TrajOpt solved in {len(stats["attempts"])} '
                         'attempt(s)', self.robot.nq, t0, stats)
        result.path = path
        return result

    def _give_up(self, t0: float, stats: dict) -> PlanResult:
        counts: dict[str, int] = {}
        for a in stats['attempts']:
            counts[a['outcome']] = counts.get(a['outcome'], 0) + 1
        stats['attempt_outcomes'] = counts
        if not counts:
            return _result(OptimOutcome.TIMEOUT, 'no attempt finished', self.robot.nq, t0, stats)
        # The budget (or max_attempts) ended the restarts: the most frequent way the attempts
        # failed is the plan's failure mode.
        outcome = OptimOutcome(max(counts, key=counts.get))
        return _result(outcome, f'no attempt succeeded: {counts}', self.robot.nq, t0, stats)


def _result(outcome: OptimOutcome, message: str, nq: int, t0: float, stats: dict) -> PlanResult:
    stats['outcome'] = outcome.value
    return PlanResult(_PLAN_STATUS[outcome], message, np.zeros((0, nq)),
                      time.monotonic() - t0, stats)


_SOLVERS: dict[str, TrajOptSolver] = {}


def plan(robot: RobotModel, objects, q_start, goal_configs, budget_s: float, seed: int,
         config: TrajOptConfig = TrajOptConfig(),
         check_step_rad: float = VictimConfig.check_step_rad) -> PlanResult:
    """Plan with TrajOpt in this process (the Tesseract robot loads once per robot and config).

    ``objects``: our ``SceneObject``s (boxes, spheres, cylinders). See ``TrajOptSolver.plan``;
    ``TrajOptVictim`` (``trajopt_victim``) runs this in a watched worker process.
    """
    key = f'{robot.hash}/{config!r}/{check_step_rad!r}'
    if key not in _SOLVERS:
        _SOLVERS[key] = TrajOptSolver(robot, config, check_step_rad)
    solver = _SOLVERS[key]
    solver.set_objects([s for o in objects for s in o.shapes])
    return solver.plan(q_start, goal_configs, budget_s, seed)
