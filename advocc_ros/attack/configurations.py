"""Coverage over configurations: which candidate boxes touch which robot configurations.

The lattice relation matches ``ours``: a box centred at candidate c covers configuration q when
a voxel centre inside the robot's links at q lies in U(c), the (2k+1)^3 voxel cube of the box.
Links are rasterized with the heatmap's solid look-up tables in a compiled kernel, only where a
candidate is near, so a configuration costs ~0.1 ms.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from advocc_ros import kernels
from advocc_ros.attack.coverage import box_sum
from advocc_ros.attack.region import SearchRegion
from advocc_ros.heatmap import link_tables, placement_arrays
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel


class _Lattice:
    """What the kernel takes for configurations ``Q`` in ``region``'s window: the candidates'
    ids, the packed link tables, the links' placements, the window's origin, the cube
    half-width k, the k-padded mask of voxels with a candidate within k (with each column's
    first and last of them) and a fresh stamp."""

    def __init__(self, robot: RobotModel, world: CollisionWorld, Q: np.ndarray,
                 region: SearchRegion, shrink: int, placements):
        grid = region.grid
        self.tables = link_tables(robot, region.lut_pitch_m)
        self.R, self.t = placement_arrays(world, Q) if placements is None else placements
        self.origin_m = np.asarray(grid.origin_m) + np.asarray(region.lo) * grid.voxel_m
        self.voxel_m = grid.voxel_m
        self.k = max(region.k - shrink, 0)
        self.near = np.pad(box_sum(region.candidates.astype(np.float64), self.k) > 0, self.k)
        self.near_z = _column_spans(self.near)
        cand = np.argwhere(region.candidates)
        self.cand_id = np.full(region.candidates.shape, -1, dtype=np.int64)
        self.cand_id[tuple(cand.T)] = np.arange(len(cand))
        self.stamp = np.full(self.near.shape, -1, dtype=np.int64)
        self.packed = self.tables.kernel_tables()

    def scan(self, cover: np.ndarray, union: bool, starts: np.ndarray | None = None) -> None:
        """The kernel (``kernels.cover``) into ``cover`` and ``self.stamp``: ``cover[r,
        cand_id[c]] = True`` for every candidate c whose cube U(c) (half-width k voxels)
        holds a voxel centre inside a link of a configuration s of row r (the
        configurations ``starts[r]`` to ``starts[r + 1]``; default one row a configuration).
        Voxels with no candidate around them are skipped (those beyond a column's first and
        last such voxel, ``near_z``, or beyond the link table's span of the column are not
        even visited), and so are voxels another link or configuration of the same row
        already did (the states of a ray overlap). With ``union``, ``cover`` is not written:
        ``stamp >= 0`` marks the voxels inside a link at some configuration (the union of
        the bodies), and a voxel one row filled is not tested again. Rows run in parallel (a
        voxel's stamp only ever skips work its row has claimed, so a race costs a repeated,
        idempotent write, never a missed one)."""
        if starts is None:
            starts = np.arange(len(self.R) + 1)
        kernels.cover(cover, starts, self.cand_id, self.near, self.near_z, self.stamp, union,
                      self.origin_m, self.voxel_m, self.k, self.R, self.t, self.packed)


def cover_matrix(robot: RobotModel, world: CollisionWorld, Q: np.ndarray,
                 region: SearchRegion, shrink: int = 0,
                 placements: tuple[np.ndarray, np.ndarray] | None = None,
                 rays: np.ndarray | None = None) -> sparse.csr_matrix:
    """(len(Q), n_candidates) sparse 0/1 (one row a ray with ``rays``): box at candidate j
    covers configuration i; ``shrink`` voxels off the box's half-width ask for a deeper
    contact. ``placements``: ``placement_arrays(world, Q)`` if the caller has them already.
    ``rays``: the ray of each
    configuration (0, 1, ... in order); then one row a ray, covered when one of its
    configurations is (a box that touches a state of a ray cuts it)."""
    n_cand = int(region.candidates.sum())
    starts = None if rays is None else _row_starts(rays)
    n_rows = len(Q) if starts is None else len(starts) - 1
    if not len(Q) or not n_cand:
        return sparse.csr_matrix((n_rows, n_cand))
    dense = np.zeros((n_rows, n_cand), dtype=np.bool_)
    _Lattice(robot, world, Q, region, shrink, placements).scan(dense, False, starts)
    indptr, indices = kernels.dense_to_csr(dense)
    return sparse.csr_matrix((np.ones(len(indices)), indices, indptr), shape=dense.shape)


def _column_spans(mask: np.ndarray) -> np.ndarray:
    """(nx, ny, 2): the first and the last z index of ``mask``'s True voxels in each column
    (first > last in a column without any)."""
    nz = mask.shape[2]
    spans = np.empty(mask.shape[:2] + (2,), dtype=np.int64)
    spans[..., 0] = np.where(mask.any(axis=2), mask.argmax(axis=2), nz)
    spans[..., 1] = nz - 1 - mask[:, :, ::-1].argmax(axis=2)
    return spans


def _row_starts(rays: np.ndarray) -> np.ndarray:
    """The first index of each ray of ``rays`` (sorted: 0, 1, ...) and the end."""
    return np.searchsorted(rays, np.arange(int(rays[-1]) + 2 if len(rays) else 1))


def touching_mask(robot: RobotModel, world: CollisionWorld, Q: np.ndarray,
                  region: SearchRegion) -> np.ndarray:
    """Mask of ``region``'s candidates that cover at least one configuration of ``Q`` (the
    rows of ``cover_matrix`` or-ed, at a fraction of its cost): the union of the bodies is
    filled once, then widened by the cube."""
    mask = np.zeros(region.candidates.shape, dtype=bool)
    if not len(Q) or not region.candidates.any():
        return mask
    lattice = _Lattice(robot, world, Q, region, 0, None)
    lattice.scan(np.zeros((0, 0), dtype=np.bool_), union=True)
    k = lattice.k
    reach = box_sum((lattice.stamp >= 0).astype(np.float64), k) > 0
    inner = reach[k:reach.shape[0] - k, k:reach.shape[1] - k, k:reach.shape[2] - k]
    return inner & region.candidates


__all__ = ['cover_matrix', 'touching_mask']
