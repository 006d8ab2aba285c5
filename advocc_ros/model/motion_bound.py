"""How far a robot's collision geometry can move per rad of joint motion (a per-robot bound L).

The continuous certificate (``advocc_ros.planning.certificate``) and the ``solvable`` guard need a
number that no configuration can exceed: along a straight joint-space segment of L2 length ``s``
no point of a collision geometry ``g`` moves more than ``L_g * s`` (and, for a self pair, no
point of one geometry moves more than ``L_ab * s`` relative to the other). It is derived from
the kinematic chain and the geometry's extent, configuration-independently:

- a revolute joint ``j`` moves a point ``x`` at speed ``|qdot_j| * dist(x, axis_j)``, and
  ``dist(x, axis_j) <= R_jg``: for the geometry's own joint, the largest distance of its points
  from the axis; for an ancestor joint, the chain offsets from ``j`` down to ``g``'s joint
  (``|translation|`` of each joint placement; a prismatic joint on the way adds its largest
  travel) plus the largest distance of ``g``'s points from its joint's origin;
- a prismatic joint moves every point at ``|qdot_j|`` (``R_jg = 1`` m/m);
- by the triangle inequality and Cauchy-Schwarz, ``|xdot| <= sum_j |qdot_j| R_jg
  <= ||qdot||_2 * sqrt(sum_j R_jg^2) = ||qdot||_2 * L_g``;
- a self pair (a, b) moves relatively only through the joints that move exactly one of them
  (the shared ones move both rigidly), so ``L_ab = sqrt(sum over those joints of R_ja^2 +
  R_jb^2)``.

The points are the geometry's mesh vertices (the convex hull the planners check has a subset of
them as vertices, and a distance is convex, so its maximum over the hull is at a vertex); a
primitive is bounded by a few points and a padding radius (a box: its corners, exact; a sphere:
its centre + radius; a cylinder or capsule: its axis ends + radius).
"""

from __future__ import annotations

import dataclasses

import coal
import numpy as np
import pinocchio as pin

_AXES = {'JointModelRX': (1.0, 0.0, 0.0), 'JointModelRY': (0.0, 1.0, 0.0),
         'JointModelRZ': (0.0, 0.0, 1.0)}
_REVOLUTE = frozenset(_AXES) | {'JointModelRevoluteUnaligned'}
_PRISMATIC = frozenset({'JointModelPX', 'JointModelPY', 'JointModelPZ',
                        'JointModelPrismaticUnaligned'})


class MotionBoundError(ValueError):
    """A joint type the bound does not cover (only revolute and prismatic joints are)."""


@dataclasses.dataclass(frozen=True, eq=False)
class MotionBound:
    """Per-geometry and per-pair bounds [m per rad of L2 joint motion; m/m for prismatic]."""

    lever_m: np.ndarray
    """(nv, n_geoms) ``R_jg``: bound on the speed of any point of geometry g per unit of joint
    j's velocity [m/rad]; 0 where joint j does not move g."""
    link_m_per_rad: np.ndarray
    """(n_geoms,) ``L_g = sqrt(sum_j R_jg^2)``: bound on any point of g's displacement per rad
    of L2 joint motion [m/rad] (0 for geometry fixed to the base)."""

    @property
    def max_m_per_rad(self) -> float:
        """L: the bound for every point of every geometry [m/rad]."""
        return float(self.link_m_per_rad.max(initial=0.0))

    def pair_m_per_rad(self, a: int, b: int) -> float:
        """Bound on the relative displacement of geometries ``a`` and ``b`` [m/rad]."""
        moves = self.lever_m > 0
        only_one = moves[:, a] ^ moves[:, b]
        return float(np.sqrt(np.sum(self.lever_m[only_one, a] ** 2
                                    + self.lever_m[only_one, b] ** 2)))

    def pairs_m_per_rad(self, pairs, n_links: int) -> np.ndarray:
        """Bound per collision pair ``(first, second)``: a self pair when both are robot
        geometries (index < ``n_links``), else a (link, static object) pair [m/rad]."""
        return np.array([self.pair_m_per_rad(a, b) if b < n_links
                         else self.link_m_per_rad[a] for a, b in pairs], dtype=float)

    def to_json(self, names) -> dict:
        return {'max_m_per_rad': round(self.max_m_per_rad, 6),
                'link_m_per_rad': {n: round(float(v), 6)
                                   for n, v in zip(names, self.link_m_per_rad)}}


def _support(geometry: coal.CollisionGeometry) -> tuple[np.ndarray, float]:
    """(points (K, 3), pad [m]): every point of ``geometry`` is within ``pad`` of the convex
    hull of ``points`` (in the geometry's own frame)."""
    if isinstance(geometry, coal.Box):
        h = np.asarray(geometry.halfSide, float)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return corners * h, 0.0
    if isinstance(geometry, coal.Sphere):
        return np.zeros((1, 3)), float(geometry.radius)
    if isinstance(geometry, (coal.Cylinder, coal.Capsule, coal.Cone)):
        half = float(geometry.halfLength)
        return np.array([[0.0, 0.0, -half], [0.0, 0.0, half]]), float(geometry.radius)
    if isinstance(geometry, coal.BVHModelBase):
        return np.asarray(geometry.vertices(), float).reshape(-1, 3), 0.0
    if isinstance(geometry, coal.ConvexBase):
        return np.asarray(geometry.points(), float).reshape(-1, 3), 0.0
    raise MotionBoundError(f'no motion bound for collision geometry {type(geometry).__name__}')


def _joint_offset_m(model: pin.Model, k: int) -> float:
    """Largest distance between joint k's origin and its parent's, over joint k's range."""
    offset = float(np.linalg.norm(model.jointPlacements[k].translation))
    if model.joints[k].shortname() in _PRISMATIC:
        i = model.joints[k].idx_q
        offset += max(abs(model.lowerPositionLimit[i]), abs(model.upperPositionLimit[i]))
    return offset


def motion_bound(model: pin.Model, geom_model: pin.GeometryModel) -> MotionBound:
    """The bound of the module docstring for every geometry of ``geom_model``."""
    kinds = [model.joints[j].shortname() for j in range(model.njoints)]
    for j in range(1, model.njoints):
        if kinds[j] not in _REVOLUTE | _PRISMATIC:
            raise MotionBoundError(f'joint {model.names[j]}: no motion bound for {kinds[j]} '
                                   '(revolute and prismatic joints only)')
    lever = np.zeros((model.nv, geom_model.ngeoms))
    for g, geom in enumerate(geom_model.geometryObjects):
        points, pad = _support(geom.geometry)
        points = points @ geom.placement.rotation.T + geom.placement.translation
        own = int(geom.parentJoint)
        offset = float(np.linalg.norm(points, axis=1).max()) + pad  # from own joint's origin
        j, chain = own, 0.0
        while j > 0:
            v = model.joints[j].idx_v
            if kinds[j] in _PRISMATIC:
                lever[v, g] = 1.0
            elif j == own and kinds[j] in _AXES:
                axis = np.asarray(_AXES[kinds[j]])
                lever[v, g] = float(np.linalg.norm(np.cross(points, axis), axis=1).max()) + pad
            else:
                lever[v, g] = chain + offset
            chain += _joint_offset_m(model, j)
            j = model.parents[j]
    return MotionBound(lever, np.sqrt(np.sum(lever ** 2, axis=0)))


__all__ = ['MotionBound', 'MotionBoundError', 'motion_bound']
