"""Batched kinematics: forward kinematics of many configurations (to one frame, or to every
joint the links hang on) and damped-least-squares IK for many attempts at once, in compiled
kernels (``advocc_ros.kernels``, C).

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

import numpy as np
import pinocchio as pin

from advocc_ros import kernels

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
        supports = all(k is not None and model.joints[j].nq == 1 for j, k in zip(joints, kinds)) \
            and len(joints) <= kernels.MAX_JOINTS and model.nq <= kernels.MAX_JOINTS
        if not supports:
            joints, kinds = [], []
        return cls(supports,
                   np.array([model.jointPlacements[j].homogeneous for j in joints]
                            ).reshape(-1, 4, 4),
                   np.array([k[1] for k in kinds]).reshape(-1, 3),
                   np.array([k[0] for k in kinds], dtype=np.bool_),
                   np.array([model.joints[j].idx_q for j in joints], dtype=np.int64))

    def chain(self, T_joint_frame: np.ndarray, nq: int) -> kernels.Chain:
        """These joints as the kernels read them, ending in ``T_joint_frame``."""
        return kernels.Chain(self.T_parent_joint, self.axis, self.revolute, self.index_q,
                             T_joint_frame, nq)


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
        self.chain = self.joints.chain(self.T_joint_frame, self.nq)

    def frame(self, Q: np.ndarray) -> np.ndarray:
        """T_base_frame (N, 4, 4) of the configurations ``Q`` (N, nq)."""
        Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, self.nq)
        out = np.empty((len(Q), 4, 4))
        if len(Q):
            kernels.frames(self.chain, Q, out)
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
        """Joint id -> its column among the joints' frames (the base, joint 0, last)."""
        self.parent = np.array([self.column[model.parents[j]] if model.parents[j] > 0 else -1
                                for j in joints], dtype=np.int64)
        self.chain = self.joints.chain(np.eye(4), self.nq)

    def placed(self, Q: np.ndarray, joints: list[int], placements: np.ndarray) -> np.ndarray:
        """(N, len(joints), 4, 4): ``T_base_joint @ placements[l]`` of joint ``joints[l]`` at
        each configuration of ``Q`` (a geometry on each joint); only when ``supports``."""
        Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, self.nq)
        return kernels.link_frames(self.chain, self.parent, Q,
                                   [self.column[j] for j in joints], placements)


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
        return kernels.contains(T_base_link, *self.arrays())

    def arrays(self) -> tuple:
        """What the kernels read: (T_center, T_link_tool, pos_tol, rot_tol)."""
        return self.T_center, self.T_link_tool, self.pos_tol, self.rot_tol


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
        kernels.dls(chain.chain, Q, done, T_target, iterations, damping, max_step, lower, upper,
                    *region.arrays())
    return Q, done


__all__ = ['ChainKinematics', 'PoseBox', 'dls']
