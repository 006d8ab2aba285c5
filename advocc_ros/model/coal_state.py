"""coal's one process-wide numerical setting, fixed before any query so that results never
depend on what a process computed first.

coal 3.0's Box support function (``getShapeSupport(const Box*, ...)``, support_functions.cpp)
keeps ``static const CoalScalar inflate = (dir.array() == 0).any() ? 1 + 1e-10 : 1.``: the
first Box support query of a process decides it, for the life of the process. When that first
direction has an exactly zero component (GJK's default initial guess (1, 0, 0) against a box
aligned with the frame it is seen from, e.g. a table under a robot's base link), the negative
faces of every box are pushed out by 1e-10 of its half-size; any other first query leaves every
box exact. Distances and contacts involving boxes then differ between processes (3.5e-11 m for
the 0.7 m table of table_pick), enough to change heatmap weights and which voxel an attack picks
(measured: another first box on table_pick after a goal-region IK check on another scene ran
first in the same process).

:func:`exact_boxes` makes the first Box query one whose directions have no zero component
(boxes stay exact), then measures the setting; ``advocc_ros.model.robot`` calls it at import,
before any geometry of ours exists to be queried. A process that queried coal boxes before
importing us keeps what its first query chose: a warning says so.
"""

from __future__ import annotations

import functools
import logging

import coal
import numpy as np
import pinocchio as pin

log = logging.getLogger(__name__)

_EXACT_TOL = 1e-13
"""|measured inflation| below this is exact (coal's alternative is 1e-10: three decades above
the probe's rounding)."""


def _convex(points: np.ndarray) -> coal.Convex:
    return coal.Convex.convexHull(list(np.asarray(points, dtype=float)), False, None)


def _first_box_query() -> None:
    """A GJK distance between a tetrahedron and a box turned by a generic rotation: every
    direction the box's support function sees has three non-zero components."""
    tetra = _convex([[0, 0, 0], [0.1, 0.02, 0], [0.03, 0.1, 0.01], [0.02, 0.03, 0.1]])
    T_box = coal.Transform3s(pin.exp3(np.array([0.3, -0.7, 1.1])), np.zeros(3))
    coal.distance(tetra, coal.Transform3s(np.eye(3), np.array([0.71, 0.53, 0.37])),
                  coal.Box(0.2, 0.3, 0.4), T_box, coal.DistanceRequest(), coal.DistanceResult())


def box_inflation() -> float:
    """coal's Box inflation in this process, measured: 0 when boxes are exact, ~1e-10 when the
    process's first Box query inflated them (relative to the half-size). It queries a box, so
    in a process that has made none it fixes the setting itself (inflated): call
    :func:`exact_boxes` first."""
    tetra = _convex([[-3, 0, 0], [-4, 1, 0], [-4, -1, 1], [-4, -1, -1]])  # apex 2 from the face
    distance_m = coal.distance(tetra, coal.Transform3s(), coal.Box(2.0, 2.0, 2.0),
                               coal.Transform3s(), coal.DistanceRequest(), coal.DistanceResult())
    return 2.0 - distance_m  # half-size 1 m: the gap's shrink is the relative inflation


@functools.cache
def exact_boxes() -> bool:
    """Fix coal's Box setting to exact if this process has not queried a box yet (once per
    process); whether boxes are exact. Warns when an earlier query had inflated them."""
    _first_box_query()
    inflation = box_inflation()
    if abs(inflation) < _EXACT_TOL:
        return True
    log.warning('coal inflates every box by %.3g of its half-size in this process (a box query '
                'ran before advocc_ros was imported): distances to boxes differ from other '
                'processes by that much, and so may heatmaps and attacks', inflation)
    return False


__all__ = ['box_inflation', 'exact_boxes']
