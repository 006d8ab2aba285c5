"""The robot's body at many configurations, and exact tests of an axis-aligned box against it.

The goal samples (``attack.goals``), the passage tube (``attack.judge``) and the witness's guard
states (``attack.solvable``) all ask which configurations a candidate box touches. Every answer
is coal's on the link hulls; a bounding-box pre-test in numpy picks the (configuration, link)
pairs worth asking, so a box far from most bodies costs a few array operations.
"""

from __future__ import annotations

import coal
import numpy as np

from advocc_ros.heatmap import placement_arrays
from advocc_ros.model.collision import CollisionWorld


class LinkBoxes:
    """The link hulls of ``world``'s robot placed at each configuration of ``Q``."""

    def __init__(self, world: CollisionWorld, Q: np.ndarray):
        Q = np.asarray(Q, dtype=float).reshape(-1, world.robot.nq)
        self.links = [g.geometry for g in world.geom_model.geometryObjects[:world.n_links]]
        self.R, self.t = placement_arrays(world, Q)
        """(n, links, 3, 3) and (n, links, 3): ``T_base_link`` of each link at each q."""
        lo, hi = np.empty((len(self.links), 3)), np.empty((len(self.links), 3))
        for k, geometry in enumerate(self.links):
            geometry.computeLocalAABB()
            lo[k], hi[k] = geometry.aabb_local.min_, geometry.aabb_local.max_
        self.centres_m = np.einsum('nlij,lj->nli', self.R, (lo + hi) / 2) + self.t
        """(n, links, 3) centre of each link's bounding box at each configuration."""
        self._half_m = (hi - lo) / 2
        """(links, 3) half extents of each link's bounding box in its own frame [m]."""
        self._reach_m = np.einsum('nlij,lj->nli', np.abs(self.R), self._half_m)
        """(n, links, 3) half extents of the world-aligned box around each link box."""
        self._request = coal.CollisionRequest()

    def __len__(self) -> int:
        return len(self.R)

    def overlapping(self, center_m: np.ndarray, half_m: float, among=None) -> np.ndarray:
        """(configuration, link) flat indices whose link box may meet the axis-aligned cube
        (centre, half edge), nearest first: not separated on the world axes nor on the link
        box's own axes (a subset of the separating-axis test, so it never drops a pair that
        meets); only configurations of the bool mask ``among`` when given."""
        d = (self.centres_m - center_m).reshape(-1, 3)
        near = np.all(np.abs(d) <= half_m + self._reach_m.reshape(-1, 3), axis=1)
        if among is not None:
            near &= np.repeat(among, len(self.links))
        near = np.flatnonzero(near)
        R = self.R.reshape(-1, 3, 3)[near]
        along = np.abs(np.einsum('kij,ki->kj', R, d[near]))
        links = near % len(self.links)
        near = near[np.all(along <= self._half_m[links] + half_m * np.abs(R).sum(axis=1),
                           axis=1)]
        return near[np.argsort(np.linalg.norm(d[near], axis=1), kind='stable')]

    def _collide(self, box: coal.Box, tf: coal.Transform3s, flat: int) -> bool:
        s, li = divmod(int(flat), len(self.links))
        link_tf = coal.Transform3s(self.R[s, li], self.t[s, li])
        return coal.collide(box, tf, self.links[li], link_tf, self._request,
                            coal.CollisionResult())

    def blocked_by(self, center_m: np.ndarray, box_size_m: float, among=None) -> np.ndarray:
        """bool (n,): configurations whose body the axis-aligned cube of edge ``box_size_m`` at
        ``center_m`` touches (of the bool mask ``among`` when given; the others are False)."""
        center_m = np.asarray(center_m, dtype=float)
        out = np.zeros(len(self), dtype=bool)
        box = coal.Box(box_size_m, box_size_m, box_size_m)
        tf = coal.Transform3s(np.eye(3), center_m)
        for flat in self.overlapping(center_m, box_size_m / 2, among):
            s = flat // len(self.links)
            if not out[s]:
                out[s] = self._collide(box, tf, flat)
        return out

    def touched_by(self, center_m: np.ndarray, box_size_m: float) -> bool:
        """Whether the cube touches the body at any configuration (stops at the first)."""
        center_m = np.asarray(center_m, dtype=float)
        box = coal.Box(box_size_m, box_size_m, box_size_m)
        tf = coal.Transform3s(np.eye(3), center_m)
        return any(self._collide(box, tf, flat)
                   for flat in self.overlapping(center_m, box_size_m / 2))


__all__ = ['LinkBoxes']
