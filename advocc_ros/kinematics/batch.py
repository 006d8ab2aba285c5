"""Batched kinematics: forward kinematics of many configurations (to one frame, or to every
joint the links hang on) and damped-least-squares IK for many attempts at once, in compiled
kernels.

Goal sampling is the online phase's largest cost when every IK runs one configuration at a time
through pinocchio (~4-16 ms per converged sample on the Panda). Here the chain to one frame is
read once from the pinocchio model into arrays, and the IK runs every attempt's whole loop
(kinematics, Jacobian, a 6x6 Cholesky solve) in compiled code. Revolute and prismatic joints
(aligned or not) are supported, which covers the serial arms the tool loads;
``ChainKinematics.supports`` tells. The kinematics agree with pinocchio's
``framesForwardKinematics`` to round-off, and the compiled IK takes the steps of pinocchio's
one-at-a-time ``kinematics.ik.dls_ik`` (test/test_batch_ik.py).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
import pinocchio as pin

_AXES = {'X': (1.0, 0.0, 0.0), 'Y': (0.0, 1.0, 0.0), 'Z': (0.0, 0.0, 1.0)}


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


@dataclasses.dataclass(frozen=True)
class _JointArrays:
    """Joints of a pinocchio model (parents first) as the compiled kernels read them."""

    supports: bool
    """Whether every joint is one the kernels model (else use pinocchio); the arrays are empty
    when not."""
    T_parent_joint: np.ndarray
    """(n, 4, 4) placement of each joint frame in its parent joint's frame (q = 0)."""
    axis: np.ndarray
    """(n, 3) unit axis of each joint in its own frame."""
    revolute: np.ndarray
    """(n,) revolute (else prismatic)."""
    index_q: np.ndarray
    """(n,) each joint's index in q."""

    @classmethod
    def of(cls, model: pin.Model, joints: list[int]) -> '_JointArrays':
        kinds = [_joint_kind(model.joints[j]) for j in joints]
        supports = all(k is not None and model.joints[j].nq == 1 for j, k in zip(joints, kinds))
        if not supports:
            joints, kinds = [], []
        return cls(supports,
                   np.array([model.jointPlacements[j].homogeneous for j in joints]
                            ).reshape(-1, 4, 4),
                   np.array([k[1] for k in kinds]).reshape(-1, 3),
                   np.array([k[0] for k in kinds], dtype=np.bool_),
                   np.array([model.joints[j].idx_q for j in joints], dtype=np.int64))


class ChainKinematics:
    """The kinematic chain from the base to one frame, as the compiled kernels read it."""

    def __init__(self, model: pin.Model, frame_id: int):
        frame = model.frames[frame_id]
        chain = []
        j = frame.parentJoint
        while j > 0:
            chain.append(j)
            j = model.parents[j]
        self.joints = _JointArrays.of(model, chain[::-1])
        self.supports = self.joints.supports
        """Whether every joint of the chain is one the kernels model (else use pinocchio)."""
        self.T_joint_frame = frame.placement.homogeneous
        self.nq = model.nq

    def frame(self, Q: np.ndarray) -> np.ndarray:
        """T_base_frame (N, 4, 4) of the configurations ``Q`` (N, nq)."""
        Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, self.nq)
        out = np.empty((len(Q), 4, 4))
        if len(Q):
            a = self.joints
            _frames(Q, a.T_parent_joint, a.axis, a.revolute, a.index_q, self.T_joint_frame, out)
        return out


class JointFrames:
    """T_base_joint of chosen joints of a pinocchio model (with their ancestors) for many
    configurations in one compiled pass: what the links' placements need
    (``CollisionWorld.link_transforms``), one forward kinematics per configuration without a
    Python step per configuration."""

    def __init__(self, model: pin.Model, joint_ids: list[int]):
        needed = set()
        for j in joint_ids:
            while j > 0 and j not in needed:
                needed.add(j)
                j = model.parents[j]
        joints = sorted(needed)  # pinocchio numbers a parent before its children
        self.joints = _JointArrays.of(model, joints)
        self.supports = self.joints.supports
        """Whether every joint is one the kernel models (else use pinocchio)."""
        self.nq = model.nq
        self.column = {j: i for i, j in enumerate(joints)} | {0: len(joints)}
        """Joint id -> its index in ``frames``' second axis (the base, joint 0, last)."""
        self.parent = np.array([self.column[model.parents[j]] if model.parents[j] > 0 else -1
                                for j in joints], dtype=np.int64)

    def frames(self, Q: np.ndarray) -> np.ndarray:
        """T_base_joint (N, n_joints + 1, 4, 4) at the configurations ``Q`` (N, nq), joints
        in ``column``'s order; only when ``supports``."""
        Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, self.nq)
        out = np.empty((len(Q), len(self.parent) + 1, 4, 4))
        out[:, -1] = np.eye(4)
        if len(Q):
            a = self.joints
            _joint_frames(Q, self.parent, a.T_parent_joint, a.axis, a.revolute, a.index_q, out)
        return out


@dataclasses.dataclass(frozen=True)
class PoseBox:
    """A goal region as the IK's stopping test: the tool (``T_link_tool`` on the chain's frame)
    within ``pos_tol`` [m] per axis of ``T_center``'s origin, in its frame, and its rotation
    vector relative to ``T_center`` within ``rot_tol`` [rad] per axis."""

    T_center: np.ndarray
    T_link_tool: np.ndarray
    pos_tol: np.ndarray
    rot_tol: np.ndarray

    def contains(self, T_base_link: np.ndarray) -> np.ndarray:
        """(N,) whether each link pose (N, 4, 4) puts the tool in the box."""
        T_base_link = np.ascontiguousarray(T_base_link, dtype=float).reshape(-1, 4, 4)
        out = np.zeros(len(T_base_link), dtype=np.bool_)
        if len(out):
            _contains_rows(T_base_link, self.T_center, self.T_link_tool,
                           np.asarray(self.pos_tol, float), np.asarray(self.rot_tol, float), out)
        return out


def dls(chain: ChainKinematics, Q: np.ndarray, T_target: np.ndarray, iterations: np.ndarray,
        damping: float, max_step: float, lower: np.ndarray, upper: np.ndarray, region: PoseBox
        ) -> tuple[np.ndarray, np.ndarray]:
    """Damped least squares for every row at once: ``GoalSampler``'s DLS (local Jacobian,
    steps of at most ``max_step`` in norm, clipped into the limits), row i running at most
    ``iterations[i]`` steps towards ``T_target[i]`` and stopping once its frame is in
    ``region``. Returns the last configurations and the reached flags."""
    Q = np.clip(np.array(Q, dtype=float), lower, upper)
    done = np.zeros(len(Q), dtype=np.bool_)
    if len(Q):
        _dls_rows(Q, done, np.ascontiguousarray(T_target, dtype=float),
                  np.asarray(iterations, dtype=np.int64), float(damping), float(max_step),
                  np.asarray(lower, float), np.asarray(upper, float), chain.joints.T_parent_joint,
                  chain.joints.axis, chain.joints.revolute, chain.joints.index_q,
                  chain.T_joint_frame,
                  region.T_center, region.T_link_tool, np.asarray(region.pos_tol, float),
                  np.asarray(region.rot_tol, float))
    return Q, done


@numba.njit(cache=True, nogil=True)
def _log3_row(R, out):
    """Rotation vector of the 3x3 rotation ``R`` into ``out`` (3,), stable near a half turn
    (the axis from the symmetric part there)."""
    cos = min(max((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    theta = np.arccos(cos)
    vx, vy, vz = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    if theta < 1e-6:
        scale = 0.5 + theta * theta / 12.0
        out[0], out[1], out[2] = vx * scale, vy * scale, vz * scale
    elif theta < np.pi - 1e-4:
        scale = theta / (2.0 * np.sin(theta))
        out[0], out[1], out[2] = vx * scale, vy * scale, vz * scale
    else:
        one_minus = 1.0 - cos
        i = 0
        for a in range(1, 3):
            if R[a, a] > R[i, i]:
                i = a
        ai = np.sqrt(max((R[i, i] - cos) / one_minus, 0.0))
        for a in range(3):
            out[a] = ai if a == i else (R[i, a] + R[a, i]) / (2.0 * one_minus * ai)
        if out[0] * vx + out[1] * vy + out[2] * vz < 0.0:
            for a in range(3):
                out[a] = -out[a]
        for a in range(3):
            out[a] *= theta


@numba.njit(cache=True, nogil=True)
def _mul4(A, B, out):
    """``out = A @ B`` for 4x4 rigid transforms (last row 0 0 0 1); ``out`` may be ``A``."""
    for a in range(3):
        r0, r1, r2, r3 = A[a, 0], A[a, 1], A[a, 2], A[a, 3]
        for b in range(4):
            out[a, b] = r0 * B[0, b] + r1 * B[1, b] + r2 * B[2, b] + (r3 if b == 3 else 0.0)
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@numba.njit(cache=True, nogil=True)
def _joint_motion(axis, revolute, x, M):
    """The joint's motion at value ``x`` into ``M`` (4, 4): a rotation of ``x`` rad about the
    unit ``axis`` (Rodrigues) or a translation of ``x`` m along it."""
    M[:, :] = 0.0
    M[3, 3] = 1.0
    if revolute:
        wx, wy, wz = axis[0] * x, axis[1] * x, axis[2] * x
        th = np.sqrt(wx * wx + wy * wy + wz * wz)
        if th < 1e-8:
            sa, sb = 1.0 - th * th / 6.0, 0.5 - th * th / 24.0
        else:
            sa, sb = np.sin(th) / th, (1.0 - np.cos(th)) / (th * th)
        # R = I + sa [w] + sb [w]^2, with [w]^2 = w w^T - |w|^2 I
        M[0, 0] = 1.0 + sb * (wx * wx - th * th)
        M[1, 1] = 1.0 + sb * (wy * wy - th * th)
        M[2, 2] = 1.0 + sb * (wz * wz - th * th)
        M[0, 1], M[1, 0] = -sa * wz + sb * wx * wy, sa * wz + sb * wx * wy
        M[0, 2], M[2, 0] = sa * wy + sb * wx * wz, -sa * wy + sb * wx * wz
        M[1, 2], M[2, 1] = -sa * wx + sb * wy * wz, sa * wx + sb * wy * wz
    else:
        for a in range(3):
            M[a, a] = 1.0
            M[a, 3] = axis[a] * x


@numba.njit(cache=True, nogil=True)
def _fk(q, T_pj, axis, revolute, index_q, T_jf, T, origins, axes_w, M):
    """T_base_frame into ``T`` (4, 4) at ``q``, and each joint's origin and axis in the base
    frame into ``origins`` and ``axes_w`` (what ``_jacobian`` reads); ``M``: scratch."""
    T[:, :] = 0.0
    for a in range(4):
        T[a, a] = 1.0
    for j in range(T_pj.shape[0]):
        _mul4(T, T_pj[j], T)
        for a in range(3):
            origins[j, a] = T[a, 3]
            axes_w[j, a] = T[a, 0] * axis[j, 0] + T[a, 1] * axis[j, 1] + T[a, 2] * axis[j, 2]
        _joint_motion(axis[j], revolute[j], q[index_q[j]], M)
        _mul4(T, M, T)
    _mul4(T, T_jf, T)


@numba.njit(cache=True, nogil=True)
def _jacobian(T, origins, axes_w, revolute, index_q, J):
    """The LOCAL frame Jacobian (6, nq) into ``J``, rows (linear, angular) as pinocchio's
    ``computeFrameJacobian(..., LOCAL)``, from ``_fk``'s outputs."""
    J[:, :] = 0.0
    for j in range(origins.shape[0]):
        col = index_q[j]
        aw = axes_w[j]
        if revolute[j]:
            dx, dy, dz = T[0, 3] - origins[j, 0], T[1, 3] - origins[j, 1], T[2, 3] - origins[j, 2]
            cx = aw[1] * dz - aw[2] * dy
            cy = aw[2] * dx - aw[0] * dz
            cz = aw[0] * dy - aw[1] * dx
            for a in range(3):  # R^T (axis x (p - origin)), R^T axis
                J[a, col] = T[0, a] * cx + T[1, a] * cy + T[2, a] * cz
                J[3 + a, col] = T[0, a] * aw[0] + T[1, a] * aw[1] + T[2, a] * aw[2]
        else:
            for a in range(3):
                J[a, col] = T[0, a] * aw[0] + T[1, a] * aw[1] + T[2, a] * aw[2]


@numba.njit(cache=True, nogil=True, parallel=True)
def _frames(Q, T_pj, axis, revolute, index_q, T_jf, out):
    """``out[i]`` = T_base_frame at ``Q[i]``, rows in parallel."""
    nj = T_pj.shape[0]
    for i in numba.prange(Q.shape[0]):
        origins, axes_w, M = np.empty((nj, 3)), np.empty((nj, 3)), np.empty((4, 4))
        _fk(Q[i], T_pj, axis, revolute, index_q, T_jf, out[i], origins, axes_w, M)


@numba.njit(cache=True, nogil=True)
def _joint_frames(Q, parent, T_pj, axis, revolute, index_q, out):
    """``out[i, j]`` = T_base_joint of joint j < len(parent) at ``Q[i]`` (each joint after
    its parent, ``parent[j]`` = -1 for the base). One thread: it runs in the heatmap's forked
    workers and beside other threads, where numba's parallel layer may not (~1 us a row)."""
    M = np.empty((4, 4))
    for i in range(Q.shape[0]):
        for j in range(T_pj.shape[0]):
            T = out[i, j]
            if parent[j] < 0:
                T[:, :] = T_pj[j]
            else:
                _mul4(out[i, parent[j]], T_pj[j], T)
            _joint_motion(axis[j], revolute[j], Q[i, index_q[j]], M)
            _mul4(T, M, T)


@numba.njit(cache=True, nogil=True, parallel=True)
def _contains_rows(T_links, T_center, T_link_tool, pos_tol, rot_tol, out):
    """``out[i]``: whether the link pose ``T_links[i]`` puts the tool in the box (``_in_box``),
    rows in parallel."""
    for i in numba.prange(T_links.shape[0]):
        tool, Rrel, w = np.empty((4, 4)), np.empty((3, 3)), np.empty(3)
        out[i] = _in_box(T_links[i], T_center, T_link_tool, pos_tol, rot_tol, tool, Rrel, w)


@numba.njit(cache=True, nogil=True)
def _in_box(T, T_center, T_link_tool, pos_tol, rot_tol, tool, Rrel, w):
    """``PoseBox.contains`` for one link pose (``tool``, ``Rrel``, ``w``: scratch)."""
    _mul4(T, T_link_tool, tool)
    for a in range(3):
        d = 0.0
        for b in range(3):
            d += T_center[b, a] * (tool[b, 3] - T_center[b, 3])
        if abs(d) > pos_tol[a]:
            return False
    for a in range(3):
        for b in range(3):
            Rrel[a, b] = (T_center[0, a] * tool[0, b] + T_center[1, a] * tool[1, b]
                          + T_center[2, a] * tool[2, b])
    _log3_row(Rrel, w)
    for a in range(3):
        if abs(w[a]) > rot_tol[a]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _log6_row(E, twist, Rs, w):
    """(linear, angular) twist of the rigid transform ``E`` into ``twist`` (6,), as
    pinocchio's ``log6``."""
    Rs[:, :] = E[:3, :3]
    _log3_row(Rs, w)
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if th < 1e-6:
        c = 1.0 / 12.0
    else:
        c = (1.0 - th * np.sin(th) / (2.0 * (1.0 - np.cos(th)))) / (th * th)
    p0, p1, p2 = E[0, 3], E[1, 3], E[2, 3]
    # V^-1 p = p - 0.5 w x p + c w x (w x p)
    x0, x1, x2 = w[1] * p2 - w[2] * p1, w[2] * p0 - w[0] * p2, w[0] * p1 - w[1] * p0
    y0, y1, y2 = w[1] * x2 - w[2] * x1, w[2] * x0 - w[0] * x2, w[0] * x1 - w[1] * x0
    twist[0], twist[1], twist[2] = p0 - 0.5 * x0 + c * y0, p1 - 0.5 * x1 + c * y1, \
        p2 - 0.5 * x2 + c * y2
    twist[3], twist[4], twist[5] = w[0], w[1], w[2]


@numba.njit(cache=True, nogil=True)
def _damped_solve(J, err, damping, A, x):
    """``x = (J J^T + damping I)^-1 err`` by Cholesky (symmetric positive definite); ``A``
    (6, 6): scratch."""
    nq = J.shape[1]
    for a in range(6):
        for b in range(a + 1):
            v = 0.0
            for c in range(nq):
                v += J[a, c] * J[b, c]
            A[a, b] = v + (damping if a == b else 0.0)
    for a in range(6):
        for b in range(a + 1):
            v = A[a, b]
            for c in range(b):
                v -= A[a, c] * A[b, c]
            A[a, b] = np.sqrt(v) if a == b else v / A[b, b]
    for a in range(6):
        v = err[a]
        for c in range(a):
            v -= A[a, c] * x[c]
        x[a] = v / A[a, a]
    for a in range(5, -1, -1):
        v = x[a]
        for c in range(a + 1, 6):
            v -= A[c, a] * x[c]
        x[a] = v / A[a, a]


@numba.njit(cache=True, nogil=True, parallel=True)
def _dls_rows(Q, done, T_target, iterations, damping, max_step, lower, upper, T_pj, axis,
              revolute, index_q, T_jf, T_center, T_link_tool, pos_tol, rot_tol):
    """``dls``'s loop, one row per attempt, rows in parallel (each touches only its own row)."""
    n, nq = Q.shape
    nj = T_pj.shape[0]
    for i in numba.prange(n):
        T, M, E = np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4))
        J = np.empty((6, nq))
        origins, axes_w = np.empty((nj, 3)), np.empty((nj, 3))
        Rs, w, err = np.empty((3, 3)), np.empty(3), np.empty(6)
        A, x, dq = np.empty((6, 6)), np.empty(6), np.empty(nq)
        q = Q[i]
        for step in range(iterations[i] + 1):
            _fk(q, T_pj, axis, revolute, index_q, T_jf, T, origins, axes_w, M)
            if _in_box(T, T_center, T_link_tool, pos_tol, rot_tol, E, Rs, w):
                done[i] = True
                break
            if step >= iterations[i]:
                break
            _jacobian(T, origins, axes_w, revolute, index_q, J)
            # E = T^-1 T_target
            for a in range(3):
                for b in range(4):
                    v = 0.0
                    for c in range(3):
                        v += T[c, a] * (T_target[i, c, b] - (T[c, 3] if b == 3 else 0.0))
                    E[a, b] = v
            _log6_row(E, err, Rs, w)
            _damped_solve(J, err, damping, A, x)
            norm = 0.0
            for c in range(nq):
                v = 0.0
                for a in range(6):
                    v += J[a, c] * x[a]
                dq[c] = v
                norm += v * v
            scale = min(1.0, max_step / max(np.sqrt(norm), 1e-300))
            for c in range(nq):
                q[c] = min(max(q[c] + dq[c] * scale, lower[c]), upper[c])


__all__ = ['ChainKinematics', 'PoseBox', 'dls']
