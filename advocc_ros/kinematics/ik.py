"""Inverse kinematics to goal regions: one damped-least-squares solver and its two uses.

- :func:`goal_configuration`: one deterministic solution from ``q_init`` to the goal centre
  (with ``AttackConfig.protect_goal_hand`` the attack keeps the hand clear there);
- :class:`GoalSampler`: collision-free configurations anywhere in a goal region (the planners'
  goal set, scene checks), the region's seeds first (a request's joint goal);
- :func:`goal_set`: many goal configurations fast (the ``task`` attack, goal checks).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import Callable

import numpy as np
import pinocchio as pin

from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import Scene
from advocc_ros.model.pose import SceneError

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class IkConfig:
    """Settings of :class:`GoalSampler` (``PlanningConfig`` carries the same two fields)."""

    ik_iterations: int = 100
    """DLS iterations per attempt."""
    ik_damping: float = 1e-4
    """DLS damping (lambda^2)."""


@dataclasses.dataclass(frozen=True)
class IkJob:
    """One goal-sampling attempt after its random draws: where DLS starts and what it aims at."""

    q_start: np.ndarray
    T_base_link_target: np.ndarray | None
    """4x4 homogeneous target of the link frame; None when ``q_start`` is already in the region."""
    iterations: int


def dls_ik(robot: RobotModel, data, frame_id: int, q: np.ndarray, T_target: pin.SE3,
           iterations: int, damping: float, reached: Callable[[pin.SE3, np.ndarray], bool],
           gain: float = 1.0, max_step: float | None = None, log_jacobian: bool = False
           ) -> tuple[np.ndarray, bool]:
    """Damped least squares on frame ``frame_id`` from ``q`` towards ``T_target`` (T_base_frame).

    Each iteration: forward kinematics, ``err = log6(T^-1 T_target)`` (local frame); stop when
    ``reached(T_base_frame, err)``; else ``dq = J^T (J J^T + damping I)^-1 err`` with the local
    frame Jacobian (times ``Jlog6`` when ``log_jacobian``), scaled by ``gain`` and to at most
    ``max_step`` in norm, integrated and clipped into the joint limits.
    Returns the last ``q`` and whether ``reached`` said so.
    """
    model = robot.model
    eye = np.eye(6) * damping
    for _ in range(iterations):
        pin.framesForwardKinematics(model, data, q)
        T = data.oMf[frame_id]
        iMd = T.actInv(T_target)
        err = pin.log6(iMd).vector
        if reached(T, err):
            return q, True
        jac = pin.computeFrameJacobian(model, data, q, frame_id, pin.LOCAL)
        if log_jacobian:
            jac = pin.Jlog6(iMd.inverse()) @ jac
        dq = jac.T @ np.linalg.solve(jac @ jac.T + eye, err)
        if gain != 1.0:
            dq = dq * gain
        if max_step is not None:
            norm = np.linalg.norm(dq)
            if norm > max_step:
                dq *= max_step / norm
        q = np.clip(pin.integrate(model, q, dq), robot.lower, robot.upper)
    return q, False


def seed_configurations(robot: RobotModel, goal: GoalRegion) -> np.ndarray:
    """The goal's seeds as (k, nq) arm configurations clipped into the joint limits; (0, nq) when
    it has none or they miss some of the robot's joints (seeds of another robot: ignored)."""
    if not goal.seeds:
        return np.zeros((0, robot.nq))
    index = {name: k for k, name in enumerate(goal.seed_joints)}
    missing = [j for j in robot.joint_names if j not in index]
    if missing:
        log.warning('goal seeds ignored: they miss joints %s of the robot', missing)
        return np.zeros((0, robot.nq))
    cols = [index[j] for j in robot.joint_names]
    return np.clip(np.asarray(goal.seeds, dtype=float)[:, cols], robot.lower, robot.upper)


def goal_configuration(robot: RobotModel, goal: GoalRegion, q_init: np.ndarray,
                       iterations: int = 200) -> np.ndarray | None:
    """One configuration whose tool point is at the goal centre (damped least squares from
    ``q_init``, joint limits clipped), or ``None`` if it does not converge into G.

    Deterministic and cheap (~ms): it only decides which hand pose to keep clear of boxes.
    """
    model = robot.model
    data = model.createData()
    fid = model.getFrameId(goal.link)
    for q in seed_configurations(robot, goal):  # a joint goal is the configuration to keep clear
        pin.framesForwardKinematics(model, data, q)
        if goal.contains(data.oMf[fid] * goal.tool_offset.to_se3()):
            return q
    T_des = goal.center.to_se3() * goal.tool_offset.to_se3().inverse()  # T_base_link wanted
    q, _ = dls_ik(robot, data, fid, np.array(q_init, dtype=float), T_des, iterations, 1e-6,
                  lambda T, err: np.linalg.norm(err) < 1e-4, gain=0.5, log_jacobian=True)
    pin.framesForwardKinematics(model, data, q)
    if goal.contains(data.oMf[fid] * goal.tool_offset.to_se3()):
        return q
    return None


class GoalSampler:
    """Collision-free configurations with FK inside a goal region, by damped-least-squares IK.

    Each attempt draws a target pose uniformly inside the region (position box x rotation-vector
    box) and a random seed configuration, then iterates DLS on the link frame until the tool
    pose enters the region (not necessarily the target: any point of the region will do).
    When the region has seeds (a request's joint goal), the first attempts offer them (pulled
    into the region if they are not quite inside), and every other attempt after that is a
    local walk around one (perturbed by N(0, ``walk_rad``) per joint, pulled back with at most
    ``walk_iterations`` DLS steps): the joint goal itself, its neighbourhood, and the rest of
    the region's IK branches. ``config``: anything with ``ik_iterations`` and ``ik_damping``
    (``IkConfig``, ``PlanningConfig``).
    """

    walk_rad = 0.3
    walk_iterations = 12
    max_step_rad = 0.5
    """Largest DLS step (joint-space norm): full steps from a random seed overshoot."""

    def __init__(self, robot: RobotModel, in_collision, goal: GoalRegion,
                 rng: np.random.Generator, config=IkConfig()):
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
        self.seeds = seed_configurations(robot, goal)

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
        """One IK attempt (a seed, a walk near one, or random-seed IK); a valid goal
        configuration or None."""
        return self.accept(self.solve(self.draw()))

    def draw(self) -> IkJob:
        """The next attempt's random draws (the only part that uses ``self.rng``), so its DLS
        can run elsewhere while the attempts still follow one seeded stream."""
        self.attempts += 1
        k, n = self.attempts - 1, len(self.seeds)
        if k < n:
            q = self.seeds[k]
            if self.region_distance(q) == 0.0:
                return IkJob(q, None, 0)
            return self._pull_job(q, self.config.ik_iterations)
        if n and (k - n) % 2 == 0:
            return self._pull_job(self.seeds[int(self.rng.integers(n))]
                                  + self.rng.normal(0.0, self.walk_rad, self.robot.nq),
                                  self.walk_iterations)
        T_target = self._random_target()
        q = self.rng.uniform(self.robot.lower, self.robot.upper)
        return IkJob(q, T_target.homogeneous, self.config.ik_iterations)

    def solve(self, job: IkJob) -> np.ndarray | None:
        """The job's DLS: a configuration inside the region, or None. No collision check."""
        if job.T_base_link_target is None:
            return job.q_start
        q, reached = dls_ik(self.robot, self.data, self.frame, job.q_start,
                            pin.SE3(job.T_base_link_target), job.iterations,
                            self.config.ik_damping, self._tool_in_region,
                            max_step=self.max_step_rad)
        return q if reached else None

    def accept(self, q: np.ndarray | None) -> np.ndarray | None:
        """``q`` if it is a collision-free solution (counted), else None."""
        if q is None:
            return None
        self.converged += 1
        if self.in_collision(q):
            self.colliding += 1
            return None
        return q

    def pull(self, q: np.ndarray, iterations: int) -> np.ndarray | None:
        """``q`` (clipped into the limits) pulled into the region by at most ``iterations``
        DLS steps toward a random pose of the region, or None. No collision check."""
        return self.solve(self._pull_job(q, iterations))

    def _pull_job(self, q: np.ndarray, iterations: int) -> IkJob:
        T_target = self._random_target()
        return IkJob(np.clip(q, self.robot.lower, self.robot.upper), T_target.homogeneous,
                     iterations)

    def _random_target(self) -> pin.SE3:
        """T_base_link of a tool pose drawn uniformly in the region's box."""
        return self.T_center * pin.SE3(
            pin.exp3(self.rng.uniform(-self.tol_r, self.tol_r)),
            self.rng.uniform(-self.tol_p, self.tol_p)) * self.T_tool_link

    def _tool_in_region(self, T_base_link: pin.SE3, err: np.ndarray) -> bool:
        return self.goal.contains(T_base_link * self.T_link_tool)

    def sample(self, n: int, deadline: float) -> list[np.ndarray]:
        """Up to ``n`` valid goal configurations found before ``deadline`` (monotonic time).

        The attempts follow ``self.rng`` alone, so a seeded sampler that finds its ``n`` before
        the deadline returns the same configurations on any machine; only a sampling cut short
        by the deadline (a plan's IK share of its time budget) depends on the machine's speed.
        """
        out = []
        while len(out) < n and time.monotonic() < deadline:
            q = self.attempt()
            if q is not None:
                out.append(q)
        return out


GOAL_SET_CAP_S = 30.0
"""Safety cap on :func:`goal_set`'s wall-clock time [s]; its iteration budgets decide the
result (~0.1 s for 64 samples on the Panda), so the cap is hit only when something is wrong."""


def goal_set(robot: RobotModel, collisions_batch: Callable[[np.ndarray], np.ndarray],
             in_collision: Callable[[np.ndarray], bool], goal: GoalRegion, n: int, seed: int,
             cap_s: float = GOAL_SET_CAP_S, anchors: int = 6, walk_rad: float = 0.3,
             walk_iterations: int = 12, stats: dict | None = None) -> np.ndarray:
    """Up to ``n`` collision-free configurations inside G, (k, nq), from ``seed``.

    A few IK solutions from random seeds (``anchors``: they find the distinct IK branches,
    ~4 ms each) are spread by local walks: perturb a stored solution by N(0, ``walk_rad``) per
    joint and pull it back into G with at most ``walk_iterations`` DLS steps toward a random
    pose of G (~0.3 ms each, collisions checked in batches). This explores the self-motion
    manifold and the tolerances at a tenth of the cost of a random-seed IK per sample.

    Iteration budgets (``40 * anchors`` IK attempts, ``20 * n`` walks) decide the result, so a
    seed gives the same set on an idle and on a loaded machine. ``cap_s`` is only a safety
    limit: when it cuts sampling short the result depends on the machine, which is logged as a
    warning and reported as ``stats['goal_time_cap_hit']`` (``stats``, when given, also gets
    the attempts and walks used).
    """
    rng = np.random.default_rng(seed)
    sampler = GoalSampler(robot, in_collision, goal, rng)
    deadline = time.monotonic() + cap_s
    capped = False
    found: list[np.ndarray] = []
    tries = 0
    while len(found) < min(anchors, n) and tries < 40 * anchors:
        if time.monotonic() >= deadline:
            capped = True
            break
        tries += 1
        q = sampler.attempt()
        if q is not None:
            found.append(q)
    pending: list[np.ndarray] = []
    walks = 0
    while found and len(found) < n and walks < 20 * n and not capped:
        if time.monotonic() >= deadline:
            capped = True
            break
        walks += 1
        q = sampler.pull(found[int(rng.integers(len(found)))]
                         + rng.normal(0.0, walk_rad, robot.nq), walk_iterations)
        if q is not None:
            pending.append(q)
        if len(pending) >= 16 or len(found) + len(pending) >= n:
            P = np.array(pending)
            found.extend(P[~collisions_batch(P)])
            pending = []
    if pending:
        P = np.array(pending)
        found.extend(P[~collisions_batch(P)])
    if capped:
        log.warning('goal sampling stopped at its %.1f s safety cap after %d IK attempts and %d '
                    'walks: %d of %d goal samples, not reproducible from the seed alone',
                    cap_s, tries, walks, min(len(found), n), n)
    if stats is not None:
        stats.update(goal_ik_attempts=tries, goal_walks=walks, goal_time_cap_hit=capped)
    return np.array(found[:n]).reshape(-1, robot.nq)


def start_configuration(scene: Scene, robot: RobotModel) -> np.ndarray:
    """``q_init`` of a scene, or a clear error when the scene has none."""
    if scene.start is None:
        raise SceneError(f'scene {scene.name!r} has no start configuration')
    return robot.q_from_names(list(scene.start), list(scene.start.values()),
                              f'{scene.name}.start')


__all__ = ['GOAL_SET_CAP_S', 'GoalSampler', 'IkConfig', 'IkJob', 'dls_ik', 'goal_configuration',
           'goal_set', 'seed_configurations', 'start_configuration']
