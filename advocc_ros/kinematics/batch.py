"""Batched kinematics: forward kinematics, frame Jacobians and damped-least-squares IK for many
configurations at once, in numpy.

Goal sampling is the online phase's largest cost when every IK runs one configuration at a time
through pinocchio (~4-16 ms per converged sample on the Panda). Here the chain to one frame is
read once from the pinocchio model and every step runs on (N, ...) arrays, so N attempts cost
about as much as a few single ones. Revolute and prismatic joints (aligned or not) are
supported, which covers the serial arms the tool loads; ``ChainKinematics.supports`` tells.
The results agree with pinocchio's ``framesForwardKinematics`` and ``computeFrameJacobian``
(LOCAL) to round-off (test/test_batch_ik.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

_AXES = {'X': (1.0, 0.0, 0.0), 'Y': (0.0, 1.0, 0.0), 'Z': (0.0, 0.0, 1.0)}


@dataclasses.dataclass(frozen=True)
class _Joint:
    index_q: int
    revolute: bool
    axis: np.ndarray
    """Unit axis in the joint frame."""
    T_parent_joint: np.ndarray
    """4x4 placement of the joint frame in its parent joint's frame (q = 0)."""


def _joint_kind(joint) -> tuple[bool, np.ndarray] | None:
    """(revolute, unit axis) of a one-dof revolute or prismatic pinocchio joint, else None."""
    name = joint.shortname()
    for prefix, revolute in (('JointModelR', True), ('JointModelP', False)):
        tail = name[len(prefix):]
        if name.startswith(prefix) and tail in _AXES:
            return revolute, np.array(_AXES[tail])
    if name in ('JointModelRevoluteUnaligned', 'JointModelPrismaticUnaligned'):
        axis = np.asarray(joint.extract().axis, float)
        return name.startswith('JointModelR'), axis / np.linalg.norm(axis)
    return None


class ChainKinematics:
    """The kinematic chain from the base to one frame, evaluated for many configurations."""

    def __init__(self, model: pin.Model, frame_id: int):
        frame = model.frames[frame_id]
        chain = []
        j = frame.parentJoint
        while j > 0:
            chain.append(j)
            j = model.parents[j]
        self.joints: list[_Joint] = []
        self.supports = True
        for j in reversed(chain):
            kind = _joint_kind(model.joints[j])
            if kind is None or model.joints[j].nq != 1:
                self.supports = False
                break
            self.joints.append(_Joint(model.joints[j].idx_q, kind[0], kind[1],
                                      model.jointPlacements[j].homogeneous))
        self.T_joint_frame = frame.placement.homogeneous
        self.nq = model.nq

    def frame_and_jacobian(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """T_base_frame (N, 4, 4) and the frame Jacobian in the LOCAL frame (N, 6, nq), rows
        (linear, angular) as pinocchio's ``computeFrameJacobian(..., LOCAL)``."""
        n = len(Q)
        T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        origins, axes, cols, revolute = [], [], [], []
        for jt in self.joints:
            T = T @ jt.T_parent_joint
            axis_w = T[:, :3, :3] @ jt.axis
            origins.append(T[:, :3, 3].copy())
            axes.append(axis_w)
            cols.append(jt.index_q)
            revolute.append(jt.revolute)
            T = T @ _motion(jt, Q[:, jt.index_q])
        T = T @ self.T_joint_frame
        J = np.zeros((n, 6, self.nq))
        R_t = np.transpose(T[:, :3, :3], (0, 2, 1))
        p = T[:, :3, 3]
        for origin, axis_w, col, rev in zip(origins, axes, cols, revolute):
            if rev:
                J[:, :3, col] = np.einsum('nij,nj->ni', R_t, np.cross(axis_w, p - origin))
                J[:, 3:, col] = np.einsum('nij,nj->ni', R_t, axis_w)
            else:
                J[:, :3, col] = np.einsum('nij,nj->ni', R_t, axis_w)
        return T, J

    def frame(self, Q: np.ndarray) -> np.ndarray:
        """T_base_frame (N, 4, 4)."""
        return self.frame_and_jacobian(Q)[0]


def _motion(joint: _Joint, q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) joint motion for the joint values ``q`` (N,)."""
    M = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    if joint.revolute:
        M[:, :3, :3] = exp3(joint.axis[None, :] * q[:, None])
    else:
        M[:, :3, 3] = joint.axis[None, :] * q[:, None]
    return M


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


def log3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (N, 3) of the rotation matrices ``R`` (N, 3, 3); rotations within 1e-4
    rad of a half turn go through pinocchio's ``log3`` (the closed form is ill-conditioned)."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]],
                   axis=1)
    sin = np.sin(theta)
    small = theta < 1e-6
    scale = np.where(small, 0.5 + theta ** 2 / 12, theta / (2 * np.where(small, 1.0, sin)))
    w = vee * scale[:, None]
    for i in np.flatnonzero(theta > np.pi - 1e-4):
        w[i] = pin.log3(R[i])
    return w


def log6(T: np.ndarray) -> np.ndarray:
    """Twists (N, 6), (linear, angular), of the homogeneous matrices ``T`` (N, 4, 4), as
    pinocchio's ``log6``."""
    w = log3(T[:, :3, :3])
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12, (1 - safe * np.sin(safe) / (2 * (1 - np.cos(safe))))
                 / safe ** 2)
    H = _hat(w)
    V_inv = np.eye(3) - 0.5 * H + c[:, None, None] * (H @ H)
    v = np.einsum('nij,nj->ni', V_inv, T[:, :3, 3])
    return np.concatenate([v, w], axis=1)


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverses (N, 4, 4) of rigid transforms."""
    out = np.broadcast_to(np.eye(4), T.shape).copy()
    R_t = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = R_t
    out[:, :3, 3] = -np.einsum('nij,nj->ni', R_t, T[:, :3, 3])
    return out


def dls(chain: ChainKinematics, Q: np.ndarray, T_target: np.ndarray, iterations: np.ndarray,
        damping: float, max_step: float, lower: np.ndarray, upper: np.ndarray, reached
        ) -> tuple[np.ndarray, np.ndarray]:
    """Damped least squares for every row at once: ``GoalSampler``'s DLS (local Jacobian,
    steps of at most ``max_step`` in norm, clipped into the limits), row i running at most
    ``iterations[i]`` steps towards ``T_target[i]`` and stopping when ``reached(T_frame)``
    (N,) bool says so. Returns the last configurations and the reached flags."""
    Q = np.clip(np.array(Q, dtype=float), lower, upper)
    done = np.zeros(len(Q), dtype=bool)
    active = np.arange(len(Q))
    eye = np.eye(6) * damping
    for step in range(int(iterations.max(initial=0)) + 1):
        if not len(active):
            break
        T, J = chain.frame_and_jacobian(Q[active])
        hit = reached(T)
        done[active[hit]] = True
        keep = ~hit & (iterations[active] > step)
        active, T, J = active[keep], T[keep], J[keep]
        if not len(active):
            break
        err = log6(inverse(T) @ T_target[active])
        J_t = np.transpose(J, (0, 2, 1))
        dq = np.einsum('nij,nj->ni', J_t, np.linalg.solve(J @ J_t + eye, err[..., None])[..., 0])
        norm = np.linalg.norm(dq, axis=1)
        dq *= np.minimum(1.0, max_step / np.maximum(norm, 1e-300))[:, None]
        Q[active] = np.clip(Q[active] + dq, lower, upper)
    return Q, done


__all__ = ['ChainKinematics', 'dls', 'exp3', 'inverse', 'log3', 'log6']
