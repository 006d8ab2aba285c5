"""Inverse kinematics to goal regions: one damped-least-squares solver and the one goal sampler.

- :func:`goal_configuration`: one deterministic solution from ``q_init`` to the goal centre
  (with ``AttackConfig.protect_goal_hand`` the attack keeps the hand clear there);
- :class:`GoalSampler`: collision-free configurations anywhere in a goal region, from one seeded
  stream of attempts (the region's seeds first, a request's joint goal). The planners run its
  attempts one at a time inside their clock (``attempt``); the attack, the victims' goal lists,
  the goal probe and the goal checks run the same stream many at once
  (``kinematics.goal_batch.planner_goals``, a compiled kernel that takes the same steps).
"""

from __future__ import annotations

import dataclasses
import functools
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
    data = robot.create_data()
    tool = goal.tool_offset.to_se3()
    for q in seed_configurations(robot, goal):  # a joint goal is the configuration to keep clear
        if goal.contains(robot.ee_pose(q, data, goal.link, tool)):
            return q
    T_des = goal.center.to_se3() * tool.inverse()  # T_base_link wanted
    q, _ = dls_ik(robot, data, robot.model.getFrameId(goal.link), np.array(q_init, dtype=float),
                  T_des, iterations, 1e-6, lambda T, err: np.linalg.norm(err) < 1e-4, gain=0.5,
                  log_jacobian=True)
    return q if goal.contains(robot.ee_pose(q, data, goal.link, tool)) else None


def _hat(w: np.ndarray) -> np.ndarray:
    """(N, 3, 3) skew matrices of the vectors ``w`` (N, 3)."""
    H = np.zeros((len(w), 3, 3))
    H[:, 0, 1], H[:, 0, 2], H[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    H[:, 1, 0], H[:, 2, 0], H[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return H


def exp3(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of the rotation vectors ``w`` (N, 3) (Rodrigues)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta ** 2 / 6, np.sin(theta) / safe)
    b = np.where(small, 0.5 - theta ** 2 / 24, (1 - np.cos(theta)) / safe ** 2)
    H = _hat(w)
    return np.eye(3) + a[:, None, None] * H + b[:, None, None] * (H @ H)


BATCH = 512
"""Attempts the stream draws at once (it is drawn per batch, so this is part of the result)."""


def goal_box(robot: RobotModel, goal: GoalRegion):
    """The goal region as the IK's stopping test on the goal link's pose (``GoalRegion.contains``
    with its slack of 1e-6), for the compiled kernels (``kinematics.batch.PoseBox``; imported
    here so that the planners' one-at-a-time sampling loads no compiler)."""
    from advocc_ros.kinematics.batch import PoseBox

    return PoseBox(goal.center.to_se3().homogeneous, goal.tool_offset.to_se3().homogeneous,
                   np.asarray(goal.position_tolerance_m) + 1e-6,
                   np.asarray(goal.orientation_tolerance_rad) + 1e-6)


class GoalSampler:
    """Collision-free configurations with FK inside a goal region, by damped-least-squares IK.

    The attempts follow one seeded stream (``draw``): the region's seeds (a request's joint
    goal) and the ``anchors`` first, each pulled into the region unless it is inside already;
    after them every other attempt is a local walk near one (perturbed by N(0, ``walk_rad``) per
    joint, pulled back with at most ``walk_iterations`` DLS steps), and every attempt without
    seeds or anchors, and every other one with them, starts from a uniformly random
    configuration and runs DLS towards a pose drawn uniformly in the region (position box x
    rotation-vector box) until the tool enters the region (not necessarily the target: any
    point of the region will do). ``config``: anything with ``ik_iterations`` and
    ``ik_damping`` (``IkConfig``, ``PlanningConfig``).
    """

    walk_rad = 0.3
    walk_iterations = 12
    max_step_rad = 0.5
    """Largest DLS step (joint-space norm): full steps from a random seed overshoot."""

    def __init__(self, robot: RobotModel, in_collision, goal: GoalRegion,
                 rng: np.random.Generator, config=IkConfig(), anchors: np.ndarray | None = None):
        self.robot, self.model = robot, robot.model
        self.data = robot.create_data()
        self.in_collision = in_collision
        self.goal, self.rng, self.config = goal, rng, config
        self.frame = robot.model.getFrameId(goal.link)
        self.T_link_tool = goal.tool_offset.to_se3()
        self.T_center = goal.center.to_se3()
        # abs: -0.0 passes '>= 0' but makes rng.uniform(-t, t) raise; huge tolerances overflow
        # its range (and mean nothing beyond a full turn or the robot's reach).
        self.tol_p = np.clip(np.abs(goal.position_tolerance_m), 0.0, 10.0)
        self.tol_r = np.clip(np.abs(goal.orientation_tolerance_rad), 0.0, math.pi)
        self.attempts = self.converged = self.colliding = 0
        self.seeds = seed_configurations(robot, goal)
        if anchors is not None and len(anchors):
            self.seeds = np.concatenate([self.seeds, np.reshape(anchors, (-1, robot.nq))])
        self._drawn = 0
        self._pending: tuple | None = None

    @functools.cached_property
    def box(self):
        """The region as the compiled kernels' stopping test (``goal_box``)."""
        return goal_box(self.robot, self.goal)

    def tool_pose(self, q: np.ndarray) -> pin.SE3:
        return self.robot.ee_pose(q, self.data, self.goal.link, self.T_link_tool)

    def region_distance(self, q: np.ndarray) -> float:
        """0 inside the region, else the excess position [m] + orientation [rad] error."""
        p_err, r_err = self.goal.error(self.tool_pose(q))
        dp = np.maximum(np.abs(p_err) - self.tol_p, 0.0)
        dr = np.maximum(np.abs(r_err) - self.tol_r, 0.0)
        if not (np.any(dp > 1e-6) or np.any(dr > 1e-6)):
            return 0.0
        return float(np.linalg.norm(dp) + np.linalg.norm(dr))

    def draw(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The next ``k`` attempts of the stream (class docstring): start configurations
        (k, nq), targets T_base_link (k, 4, 4) and DLS step budgets (k,)."""
        robot, rng = self.robot, self.rng
        index = self._drawn + np.arange(k)
        self._drawn += k
        starts = rng.uniform(robot.lower, robot.upper, (k, robot.nq))
        iterations = np.full(k, self.config.ik_iterations)
        ns = len(self.seeds)
        if ns:
            is_seed = index < ns
            starts[is_seed] = self.seeds[index[is_seed]]
            walk = ~is_seed & ((index - ns) % 2 == 0)
            picks = rng.integers(ns, size=int(walk.sum()))
            starts[walk] = self.seeds[picks] + rng.normal(0.0, self.walk_rad,
                                                          (len(picks), robot.nq))
            iterations[walk] = self.walk_iterations
        T = np.broadcast_to(np.eye(4), (k, 4, 4)).copy()
        T[:, :3, :3] = exp3(rng.uniform(-self.tol_r, self.tol_r, (k, 3)))
        T[:, :3, 3] = rng.uniform(-self.tol_p, self.tol_p, (k, 3))
        targets = self.T_center.homogeneous @ T @ self.T_link_tool.inverse().homogeneous
        return starts, targets, iterations

    def solve(self, q_start: np.ndarray, T_target: np.ndarray, iterations: int
              ) -> np.ndarray | None:
        """One attempt's DLS (pinocchio), the steps of the compiled kernel: from ``q_start``
        (clipped into the limits) at most ``iterations`` steps towards ``T_target``; a
        configuration inside the region, or None. No collision check."""
        q, reached = dls_ik(self.robot, self.data, self.frame,
                            np.clip(q_start, self.robot.lower, self.robot.upper),
                            pin.SE3(T_target), int(iterations) + 1, self.config.ik_damping,
                            lambda T, err: self.goal.contains(T * self.T_link_tool),
                            max_step=self.max_step_rad)
        return q if reached else None

    def attempt(self) -> np.ndarray | None:
        """The stream's next attempt, one at a time: a valid goal configuration or None."""
        if self._pending is None or self._pending[3] >= len(self._pending[0]):
            self._pending = (*self.draw(BATCH), 0)
        starts, targets, iterations, i = self._pending
        self._pending = (starts, targets, iterations, i + 1)
        self.attempts += 1
        return self.accept(self.solve(starts[i], targets[i], iterations[i]))

    def accept(self, q: np.ndarray | None) -> np.ndarray | None:
        """``q`` if it is a collision-free solution (counted), else None."""
        if q is None:
            return None
        self.converged += 1
        if self.in_collision(q):
            self.colliding += 1
            return None
        return q

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


def start_configuration(scene: Scene, robot: RobotModel) -> np.ndarray:
    """``q_init`` of a scene, or a clear error when the scene has none."""
    if scene.start is None:
        raise SceneError(f'scene {scene.name!r} has no start configuration')
    return robot.q_from_names(list(scene.start), list(scene.start.values()),
                              f'{scene.name}.start')


__all__ = ['BATCH', 'GoalSampler', 'IkConfig', 'dls_ik', 'exp3', 'goal_box', 'goal_configuration',
           'seed_configurations', 'start_configuration']
