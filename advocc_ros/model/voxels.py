"""Voxel grids and solid-volume rasterization.

A voxel is *occupied* by a solid when the voxel's centre lies inside the solid. Primitives are
tested analytically; meshes (robot links, sensed reconstructions) through a fine boolean
look-up table built once (convex solids: the hull's half-spaces; others: trimesh's surface
voxelization + fill), so each test is an array index, and a batch of thousands of
configurations is a few numpy operations. A sensed cloud
occupies the centres that fall in one of its octree leaves.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from advocc_ros.model.cloud import points_in_cloud
from advocc_ros.model.shapes import Shape

if TYPE_CHECKING:  # trimesh (0.3 s to import) loads only where a mesh is voxelized
    import trimesh


@dataclasses.dataclass(frozen=True)
class VoxelGrid:
    """Axis-aligned grid in the robot base frame.

    Voxel ``(i, j, k)`` spans ``origin_m + [i, j, k] * voxel_m`` to ``... + voxel_m``; its
    centre is ``origin_m + ([i, j, k] + 0.5) * voxel_m``.
    """

    origin_m: tuple[float, float, float]
    voxel_m: float
    shape: tuple[int, int, int]

    def __post_init__(self):
        if not (np.isfinite(self.voxel_m) and self.voxel_m > 0):
            raise ValueError(f'voxel size must be a positive number, got {self.voxel_m}')
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f'grid shape must be 3 positive integers, got {self.shape}')
        if len(self.origin_m) != 3 or not np.all(np.isfinite(self.origin_m)):
            raise ValueError(f'grid origin must be 3 finite numbers, got {self.origin_m}')

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def upper_m(self) -> np.ndarray:
        return np.asarray(self.origin_m) + np.asarray(self.shape) * self.voxel_m

    def centers(self, index: np.ndarray) -> np.ndarray:
        """Centres [m] of integer voxel indices (..., 3)."""
        return np.asarray(self.origin_m) + (np.asarray(index) + 0.5) * self.voxel_m

    def index_of(self, points_m: np.ndarray) -> np.ndarray:
        """Integer index (..., 3) of the voxel containing each point (may be out of range)."""
        return np.floor((np.asarray(points_m) - self.origin_m) / self.voxel_m).astype(np.int64)

    def to_data(self) -> dict:
        return {'origin_m': list(self.origin_m), 'voxel_m': self.voxel_m,
                'shape': list(self.shape)}


@dataclasses.dataclass(frozen=True)
class SolidLUT:
    """Boolean occupancy of one solid in its own frame at a fine pitch."""

    origin_m: np.ndarray
    """(3,) corner of the LUT in the solid's frame."""
    pitch_m: float
    filled: np.ndarray
    """(nx, ny, nz) bool."""

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh, pitch_m: float) -> 'SolidLUT':
        lo, hi = mesh.bounds
        hull = mesh.convex_hull
        if mesh.is_watertight and abs(hull.volume - mesh.volume) <= 1e-3 * hull.volume:
            # Convex solid (robot collision meshes usually are): exact half-space test of the
            # cell centres, far faster than surface voxelization + fill.
            n = np.maximum(np.ceil((hi - lo) / pitch_m).astype(int) + 2, 1)
            origin = lo - pitch_m
            axes = [origin[a] + (np.arange(n[a]) + 0.5) * pitch_m for a in range(3)]
            filled = _inside_convex(hull.face_normals, np.einsum(
                'ij,ij->i', hull.face_normals, hull.triangles[:, 0]) + 1e-12, *axes)
        else:
            vox = mesh.voxelized(pitch_m).fill()
            # trimesh's voxel centres sit at transform @ index; the cell corner is half a pitch
            # off.
            origin = np.asarray(vox.transform[:3, 3]) - 0.5 * pitch_m
            filled = np.asarray(vox.matrix, dtype=bool)
        return cls(origin, pitch_m, filled)

    def contains(self, points_local: np.ndarray) -> np.ndarray:
        idx = np.floor((points_local - self.origin_m) / self.pitch_m).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < self.filled.shape), axis=-1)
        out = np.zeros(points_local.shape[:-1], dtype=bool)
        sel = idx[ok]
        out[ok] = self.filled[sel[:, 0], sel[:, 1], sel[:, 2]]
        return out


_SURE_M = 1e-6
"""Distance from a face beyond which rounding cannot change a centre's side of it [m]."""


def _inside_convex(normals: np.ndarray, offsets: np.ndarray, x: np.ndarray, y: np.ndarray,
                   z: np.ndarray) -> np.ndarray:
    """Grid cells (x, y, z centres) with n . p <= offset for every face: (nx, ny, nz) bool.

    Per (x, y) column the solid is one z interval, so the faces are intersected with C columns
    (C x F work, not C x nz x F); a centre within ``_SURE_M`` of a face is tested directly.
    Faces with |n_z| < ``_SURE_M`` bound the column, not z."""
    X, Y = np.meshgrid(x, y, indexing='ij')
    rhs = offsets - np.outer(X.ravel(), normals[:, 0]) - np.outer(Y.ravel(), normals[:, 1])
    nz = normals[:, 2]
    steep = np.abs(nz) >= _SURE_M
    up, down = steep & (nz > 0), steep & (nz < 0)
    z_hi = np.min(rhs[:, up] / nz[up], axis=1, initial=np.inf)
    z_lo = np.max(rhs[:, down] / nz[down], axis=1, initial=-np.inf)
    slack = np.abs(nz[~steep]) * np.abs(z).max()
    flat_in = np.all(rhs[:, ~steep] - slack > _SURE_M, axis=1)
    flat_out = np.any(rhs[:, ~steep] + slack < -_SURE_M, axis=1)
    inside = (z >= z_lo[:, None] + _SURE_M) & (z <= z_hi[:, None] - _SURE_M) & flat_in[:, None]
    outside = (z < z_lo[:, None] - _SURE_M) | (z > z_hi[:, None] + _SURE_M) | flat_out[:, None]
    unsure = np.flatnonzero(~inside & ~outside)
    column, k = np.unravel_index(unsure, inside.shape)
    pts = np.stack([X.ravel()[column], Y.ravel()[column], z[k]], -1)
    filled = inside.ravel()
    filled[unsure] = np.all(pts @ normals.T <= offsets, axis=1)
    return filled.reshape(len(x), len(y), len(z))


def points_in_shape(shape: Shape, points_m: np.ndarray, lut_pitch_m: float = 0.005
                    ) -> np.ndarray:
    """Which points (..., 3) in the base frame lie inside ``shape``."""
    T = shape.pose.to_se3()
    local = (np.asarray(points_m) - T.translation) @ T.rotation
    if shape.kind == 'box':
        return np.all(np.abs(local) <= np.asarray(shape.dims) / 2, axis=-1)
    if shape.kind == 'sphere':
        return np.linalg.norm(local, axis=-1) <= shape.dims[0]
    if shape.kind == 'cylinder':
        height, radius = shape.dims
        return (np.abs(local[..., 2]) <= height / 2) & \
            (np.linalg.norm(local[..., :2], axis=-1) <= radius)
    if shape.kind == 'cloud':
        return points_in_cloud(shape, points_m)
    import trimesh
    mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    return SolidLUT.from_mesh(mesh, lut_pitch_m).contains(local)


def occupied_mask(grid: VoxelGrid, shapes: list[Shape]) -> np.ndarray:
    """Boolean grid of voxels whose centre is inside any shape."""
    mask = np.zeros(grid.shape, dtype=bool)
    for shape in shapes:
        lo, hi = shape.bounds_m()
        i0 = np.clip(grid.index_of(lo), 0, grid.shape)
        i1 = np.clip(grid.index_of(hi) + 1, 0, grid.shape)
        if np.any(i1 <= i0):
            continue
        idx = np.stack(np.meshgrid(*[np.arange(i0[a], i1[a]) for a in range(3)],
                                   indexing='ij'), axis=-1)
        inside = points_in_shape(shape, grid.centers(idx))
        sub = mask[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]]
        sub |= inside
    return mask
