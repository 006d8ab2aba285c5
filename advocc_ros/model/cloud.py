"""Sensed point clouds as scene objects: files (PLY, PCD), validation and coal octrees.

A cloud object ``{id, type: cloud, file: cloud.ply, resolution: 0.02, pose: ...}`` holds points
in the object's frame; it is occupied where an octree leaf of edge ``resolution`` holds a point.
Collision and distance use coal's ``OcTree`` built by ``coal.makeOctree`` (one hit per point, no
ray casting: the FCL/MoveIt octomap semantics), voxel occupancy uses the same leaves
(:func:`advocc_ros.model.shapes.cloud_cells`), so both agree cell for cell.
"""

from __future__ import annotations

import hashlib
import logging
import pathlib
from typing import Any, Callable

import coal
import numpy as np

from advocc_ros.limits import (MAX_CLOUD_POINTS, MAX_CLOUD_RESOLUTION_M, MAX_FILE_BYTES,
                               MIN_CLOUD_RESOLUTION_M)
from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.shapes import Pose, SceneError, Shape, cloud_cells, finite_array

log = logging.getLogger(__name__)

DEFAULT_RESOLUTION_M = 0.02
"""Octree leaf edge [m] when a cloud object does not name one."""
CLOUD_SUFFIXES = ('.ply', '.pcd')
_OCTREE_HALF_KEYS = 2 ** 15
"""Leaves per axis on each side of the origin that octomap's 16-bit keys address: a point
beyond is silently dropped by ``coal.makeOctree``, and far beyond (~10^8 m) its key overflows
and coal's distance queries on the tree segfault."""

_CLOUDS: BoundedCache = BoundedCache('cloud octrees and keys', 32)
"""(content hash, resolution, 'octree' | 'keys') -> coal.OcTree | sorted leaf keys."""


def make_cloud_shape(points, resolution_m: float = DEFAULT_RESOLUTION_M, pose: Pose = Pose(),
                     where: str = 'cloud') -> Shape:
    """Validated cloud shape: (N, 3) finite points in the shape frame, 1 <= N <=
    ``MAX_CLOUD_POINTS``, resolution within ``MIN/MAX_CLOUD_RESOLUTION_M``."""
    try:
        pts = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise SceneError(f'{where}.points: expected (N, 3) numbers') from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise SceneError(f'{where}.points: expected (N, 3) points, got shape {pts.shape}')
    if len(pts) == 0:
        raise SceneError(f'{where}.points: the cloud is empty')
    if len(pts) > MAX_CLOUD_POINTS:
        raise SceneError(f'{where}.points: {len(pts):,} points, limit {MAX_CLOUD_POINTS:,} '
                         '(MAX_CLOUD_POINTS)')
    bad = ~np.all(np.isfinite(pts), axis=1)
    if bad.any():
        raise SceneError(f'{where}.points: {int(bad.sum())} NaN/inf point(s), first at row '
                         f'{int(np.argmax(bad))}')
    res = float(finite_array([resolution_m], f'{where}.resolution', 1, positive=True)[0])
    if not MIN_CLOUD_RESOLUTION_M <= res <= MAX_CLOUD_RESOLUTION_M:
        raise SceneError(f'{where}.resolution: {res} m is outside {MIN_CLOUD_RESOLUTION_M}..'
                         f'{MAX_CLOUD_RESOLUTION_M} m (MIN/MAX_CLOUD_RESOLUTION_M)')
    reach_m = res * _OCTREE_HALF_KEYS
    far_m = float(np.abs(pts).max())
    if far_m >= reach_m:
        raise SceneError(f'{where}.points: a coordinate of {far_m:.4g} m; an octree of {res} m '
                         f'leaves reaches {reach_m:g} m from the origin (a byte-swapped or '
                         'unscaled cloud?)')
    return Shape('cloud', (res,), pose, np.ascontiguousarray(pts), None)


def read_cloud_file(path: str | pathlib.Path, where: str = 'cloud') -> np.ndarray:
    """(N, 3) xyz points of a PLY (via trimesh) or PCD (via pypcd4) file; ``SceneError``
    naming ``where`` on a missing, oversized or unreadable file."""
    path = pathlib.Path(path)
    if path.suffix.lower() not in CLOUD_SUFFIXES:
        raise SceneError(f'{where}.file: {path} is not a PLY or PCD file')
    if not path.is_file():
        raise SceneError(f'{where}.file: {path} not found')
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise SceneError(f'{where}.file: {path} is {size} bytes, limit {MAX_FILE_BYTES} '
                         '(MAX_FILE_BYTES)')
    try:
        if path.suffix.lower() == '.ply':
            import trimesh
            loaded = trimesh.load(str(path), process=False)
            points = np.asarray(loaded.vertices, dtype=float)
        else:
            from pypcd4 import PointCloud
            _check_pcd_header(path)
            pc = PointCloud.from_path(str(path))
            points = np.asarray(pc.numpy(('x', 'y', 'z')), dtype=float)
    except SceneError as exc:
        raise SceneError(f'{where}.file: {path}: {exc}') from None
    except Exception as exc:  # the readers raise many types on bad files
        raise SceneError(f'{where}.file: {path} could not be read ({exc})') from exc
    return points.reshape(-1, 3) if points.size else np.zeros((0, 3))


_PCD_SIZES = {'F': (4, 8), 'U': (1, 2, 4, 8), 'I': (1, 2, 4, 8)}
_PCD_MAX_COUNT = 1024
"""Elements of one PCD field (histogram descriptors have a few hundred; xyz has 1)."""


def _check_pcd_header(path: pathlib.Path) -> None:
    """``SceneError`` on a PCD header whose fields, sizes, counts or point numbers pypcd4
    would trust: a COUNT of 2^64 makes it build a dtype of 2^64 entries (a hang)."""
    header: dict[str, list[str]] = {}
    with open(path, 'rb') as handle:
        for raw in handle:
            words = raw.decode('ascii', 'replace').split()
            if words and not words[0].startswith('#'):
                header[words[0].upper()] = words[1:]
            if words and words[0].upper() == 'DATA' or len(header) > 64:
                break
    fields = header.get('FIELDS', [])
    sizes, types = header.get('SIZE', []), header.get('TYPE', [])
    counts = header.get('COUNT', ['1'] * len(fields))
    if not fields or not len(fields) == len(sizes) == len(types) == len(counts):
        raise SceneError(f'PCD header: FIELDS, SIZE, TYPE and COUNT must list one entry per '
                         f'field, got {len(fields)}, {len(sizes)}, {len(types)}, {len(counts)}')
    for name, size, kind, count in zip(fields, sizes, types, counts):
        if kind not in _PCD_SIZES or not size.isdigit() or int(size) not in _PCD_SIZES[kind]:
            raise SceneError(f'PCD header: field {name!r} has TYPE {kind} SIZE {size}')
        if not count.isdigit() or not 1 <= int(count) <= _PCD_MAX_COUNT:
            raise SceneError(f'PCD header: field {name!r} has COUNT {count} (1..{_PCD_MAX_COUNT})')
    for key in ('WIDTH', 'HEIGHT', 'POINTS'):
        value = (header.get(key) or ['(missing)'])[0]
        if not value.isdigit() or int(value) > MAX_CLOUD_POINTS:
            raise SceneError(f'PCD header: {key} {value} is not a number of points up to '
                             f'{MAX_CLOUD_POINTS:,} (MAX_CLOUD_POINTS)')


def cloud_shape_from_data(entry: dict, where: str, base_dir: pathlib.Path | None,
                          pose: Pose) -> Shape:
    """A ``type: cloud`` scene-file entry (``file`` or inline ``points``, ``resolution``)."""
    resolution = entry.get('resolution', DEFAULT_RESOLUTION_M)
    if 'file' in entry:
        path = pathlib.Path(str(entry['file']))
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        points = read_cloud_file(path, where)
        if len(points) and not np.all(np.isfinite(points)):  # name the file, not just the entry
            where = f'{where} ({path})'
    elif 'points' in entry:
        points = entry['points']
    else:
        raise SceneError(f'{where}: a cloud needs file (PLY/PCD) or points')
    return make_cloud_shape(points, resolution, pose, where)


def cloud_to_data(shape: Shape) -> dict[str, Any]:
    """Inline scene-file fields of a cloud shape (``points``, ``resolution``)."""
    return {'resolution': float(shape.dims[0]),
            'points': np.asarray(shape.vertices).tolist()}


def _cached(shape: Shape, name: str, make: Callable[[], Any]) -> Any:
    """``make()`` of this cloud's content, cached (clouds arrive on one node thread while
    another plans)."""
    key = (hashlib.sha256(np.ascontiguousarray(shape.vertices).tobytes()).hexdigest(),
           round(shape.dims[0], 9), name)
    return _CLOUDS.get_or_make(key, make)


def cloud_octree(shape: Shape) -> coal.OcTree:
    """coal ``OcTree`` of a cloud shape in its own frame (cached by content)."""
    return _cached(shape, 'octree', lambda: coal.makeOctree(
        np.ascontiguousarray(shape.vertices, dtype=float), shape.dims[0]))


def _leaf_keys(shape: Shape) -> np.ndarray:
    """Sorted int64 keys of the occupied leaves (cached by content)."""
    return _cached(shape, 'keys',
                   lambda: np.sort(_encode(cloud_cells(shape.vertices, shape.dims[0]))))


def points_in_cloud(shape: Shape, points_m: np.ndarray) -> np.ndarray:
    """Which points (..., 3) in the base frame lie in an occupied leaf of the cloud."""
    T = shape.pose.to_se3()
    res = shape.dims[0]
    local = (np.asarray(points_m, dtype=float) - T.translation) @ T.rotation
    keys = _encode(np.floor(local / res).astype(np.int64))
    occupied = _leaf_keys(shape)
    pos = np.clip(np.searchsorted(occupied, keys), 0, len(occupied) - 1)
    return occupied[pos] == keys


def _encode(cells: np.ndarray) -> np.ndarray:
    """One int64 per cell index (..., 3) (21 bits per axis, like octomap's 16-bit keys)."""
    c = np.clip(cells + (1 << 20), 0, (1 << 21) - 1)
    return (c[..., 0] << 42) | (c[..., 1] << 21) | c[..., 2]
