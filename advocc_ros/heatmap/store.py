"""The heatmap as data: the ``Heatmap`` dataclass, its file format and merging shards. No ROS.

File format (``.npz``, no pickle): ``format_version``, ``origin_m``, ``voxel_m``, ``shape``,
``values`` (float64 H), ``free`` (bool V_free) and ``meta_json`` (UTF-8 JSON: robot and scene
hashes, parameters, seed(s), sample counts, build time). Shards built with different seeds over
the same robot, scene and grid merge by summing. ``params.lut_pitch_fraction`` is the pitch of
the link look-up tables the build rasterized with, as a fraction of the voxel edge; the attack
rasterizes with the same tables. Files without it were built at
:data:`DEFAULT_LUT_PITCH_FRACTION`. The full description is in ``docs/formats.md``.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import pathlib
import tokenize
import zipfile
import zlib

import numpy as np

from advocc_ros.fileio import atomic_open
from advocc_ros.limits import MAX_HEATMAP_BYTES, MAX_HEATMAP_VOXELS
from advocc_ros.model.voxels import VoxelGrid

FORMAT_VERSION = 1
DEFAULT_LUT_PITCH_FRACTION = 0.25
"""Link look-up-table pitch / voxel edge of builds that do not record it (all builds used it)."""


class HeatmapError(ValueError):
    """A heatmap file that is corrupted, truncated, of another version or for another robot."""


@dataclasses.dataclass
class Heatmap:
    """H over a voxel grid, with V_free and provenance metadata."""

    grid: VoxelGrid
    values: np.ndarray
    """(nx, ny, nz) float64 accumulated weights H."""
    free: np.ndarray
    """(nx, ny, nz) bool V_free (voxels not inside scene objects at build time)."""
    meta: dict

    @property
    def lut_pitch_m(self) -> float:
        """Pitch of the link look-up tables H was rasterized with [m]."""
        params = self.meta.get('params')
        fraction = (params.get('lut_pitch_fraction', DEFAULT_LUT_PITCH_FRACTION)
                    if isinstance(params, dict) else DEFAULT_LUT_PITCH_FRACTION)
        if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) \
                or not 0 < fraction <= 1:
            raise HeatmapError(f'params.lut_pitch_fraction must be a number in (0, 1], got '
                               f'{fraction!r}')
        return self.grid.voxel_m * float(fraction)

    @property
    def robot_only(self) -> bool:
        return bool(self.meta.get('params', {}).get('robot_only', False))

    def summary(self) -> dict:
        nz = self.values > 0
        peak = np.unravel_index(int(np.argmax(self.values)), self.values.shape)
        return {
            'format_version': FORMAT_VERSION, **self.grid.to_data(),
            'voxel': self.grid.voxel_m,
            'valid_samples': self.meta.get('valid_samples'),
            'candidates': self.meta.get('candidates'),
            'build_s': self.meta.get('build_s'), 'robot_hash': self.meta.get('robot_hash'),
            'scene_hash': self.meta.get('scene_hash'), 'scene_name': self.meta.get('scene_name'),
            'seeds': self.meta.get('seeds'), 'params': self.meta.get('params'),
            'nonzero_voxels': int(nz.sum()), 'free_voxels': int(self.free.sum()),
            'total_mass': float(self.values.sum()), 'peak_value': float(self.values[peak]),
            'peak_center_m': self.grid.centers(np.array(peak)).round(4).tolist(),
        }


# --------------------------------------------------------------------------------------------
# File format

def hottest_voxels(heatmap: Heatmap, percentile: float = 80.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Centres (K, 3) [m] and H (K,) of the voxels whose H is at or above the ``percentile``
    of the non-zero voxels (80: the top 20 %), for RViz."""
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f'percentile must be in 0..100, got {percentile}')
    H = heatmap.values
    positive = H[H > 0]
    if positive.size == 0:
        return np.zeros((0, 3)), np.zeros(0)
    idx = np.argwhere(H >= max(np.percentile(positive, percentile), np.nextafter(0, 1)))
    return heatmap.grid.centers(idx), H[tuple(idx.T)]


def save_heatmap(heatmap: Heatmap, path: str | pathlib.Path) -> None:
    """Write atomically: a crash mid-write leaves any previous file intact."""
    meta = json.dumps(heatmap.meta, sort_keys=True).encode()
    with atomic_open(path, 'wb') as handle:
        np.savez_compressed(
            handle, format_version=np.array(FORMAT_VERSION, dtype=np.int64),
            origin_m=np.asarray(heatmap.grid.origin_m, dtype=np.float64),
            voxel_m=np.array(heatmap.grid.voxel_m, dtype=np.float64),
            shape=np.asarray(heatmap.grid.shape, dtype=np.int64),
            values=np.asarray(heatmap.values, dtype=np.float64),
            free=np.asarray(heatmap.free, dtype=bool),
            meta_json=np.frombuffer(meta, dtype=np.uint8))


def load_heatmap(path: str | pathlib.Path, robot_hash: str | None = None) -> Heatmap:
    """Read and validate a heatmap file; ``robot_hash`` rejects files built for another robot."""
    path = pathlib.Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise HeatmapError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as zf:
            inflated = sum(info.file_size for info in zf.infolist())
            if inflated > MAX_HEATMAP_BYTES:  # checked before inflating: no zip bomb
                raise HeatmapError(f'{path}: arrays of {inflated} bytes, limit '
                                   f'{MAX_HEATMAP_BYTES} (MAX_HEATMAP_VOXELS)')
            _check_headers(zf, path)
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError,
            NotImplementedError, SyntaxError, tokenize.TokenError) as exc:  # numpy's header
        # parser raises the last two on a garbled header dict
        if isinstance(exc, HeatmapError):
            raise
        raise HeatmapError(f'{path}: not a readable heatmap file (corrupted or truncated: '
                           f'{exc})') from exc
    required = {'format_version', 'origin_m', 'voxel_m', 'shape', 'values', 'free', 'meta_json'}
    missing = required - set(arrays)
    if missing:
        raise HeatmapError(f'{path}: not a heatmap file (missing {sorted(missing)})')
    try:
        version = int(arrays['format_version'])
    except (TypeError, ValueError, OverflowError):
        raise HeatmapError(f'{path}: format_version is not an integer') from None
    if version != FORMAT_VERSION:
        raise HeatmapError(f'{path}: format version {version}, this advocc reads '
                           f'{FORMAT_VERSION}; rebuild it with `advocc heatmap build`')
    try:
        grid = VoxelGrid(tuple(float(v) for v in arrays['origin_m']),
                         float(arrays['voxel_m']), tuple(int(v) for v in arrays['shape']))
        meta = json.loads(arrays['meta_json'].tobytes().decode())
    except (ValueError, TypeError, UnicodeDecodeError, OverflowError, RecursionError) as exc:
        raise HeatmapError(f'{path}: invalid grid or metadata ({exc})') from exc
    if grid.size > MAX_HEATMAP_VOXELS:
        raise HeatmapError(f'{path}: grid of {grid.size} voxels, limit {MAX_HEATMAP_VOXELS}')
    values, free = arrays['values'], arrays['free']
    if values.shape != grid.shape or free.shape != grid.shape:
        raise HeatmapError(f'{path}: arrays of shape {values.shape}/{free.shape} do not match '
                           f'the grid {grid.shape}')
    if values.dtype != np.float64 or free.dtype != bool:
        raise HeatmapError(f'{path}: unexpected array types {values.dtype}/{free.dtype}')
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise HeatmapError(f'{path}: H holds negative or non-finite values')
    if not isinstance(meta, dict):
        raise HeatmapError(f'{path}: metadata is not a mapping')
    heatmap = Heatmap(grid, values, free, meta)
    try:
        heatmap.lut_pitch_m
    except HeatmapError as exc:
        raise HeatmapError(f'{path}: {exc}') from None
    if robot_hash is not None:
        check_robot(heatmap, robot_hash, path)
    return heatmap


def _check_headers(zf: zipfile.ZipFile, path: pathlib.Path) -> None:
    """Each ``.npy`` member's header against its size, before numpy allocates what the header
    claims (a lying shape would ask for terabytes); object (pickled) arrays are refused."""
    for info in zf.infolist():
        with zf.open(info) as handle:
            version = np.lib.format.read_magic(handle)
            if version not in ((1, 0), (2, 0)):
                raise HeatmapError(f'{path}: {info.filename}: .npy format {version} is not one '
                                   'this advocc writes')
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) \
                else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(handle)
        if dtype.hasobject:
            raise HeatmapError(f'{path}: {info.filename} holds Python objects (pickled data), '
                               'which are never loaded')
        claimed = math.prod(shape) * dtype.itemsize
        if claimed > info.file_size:
            raise HeatmapError(f'{path}: {info.filename}: its header claims {claimed} bytes of '
                               f'data, the member holds {info.file_size}')


def check_robot(heatmap: Heatmap, robot_hash: str, path: str | pathlib.Path = 'heatmap'
                ) -> None:
    """``HeatmapError`` unless the heatmap was built for the robot of ``robot_hash``."""
    meta = heatmap.meta
    if meta.get('robot_hash') != robot_hash:
        raise HeatmapError(f'{path}: built for robot {meta.get("robot_hash")!r} '
                           f'({meta.get("robot_urdf")}), not this robot ({robot_hash})')


def locked_joints(meta: dict, urdf: str, srdf: str, group: str
                  ) -> tuple[tuple[str, float], ...] | None:
    """The locked joint values of the robot a heatmap was built for (``meta['robot']``, the
    RobotSpec of its build), when that robot is ``urdf``/``srdf``/``group``; else None (also
    for files that predate the field)."""
    spec = meta.get('robot')
    if not isinstance(spec, dict) or (spec.get('urdf'), spec.get('srdf'), spec.get('group')) \
            != (urdf, srdf, group):
        return None
    locked = spec.get('locked') or {}
    if not isinstance(locked, dict):
        return None
    try:
        return tuple(sorted((str(k), float(v)) for k, v in locked.items()))
    except (TypeError, ValueError):
        return None


def _comparable(meta: dict, key: str):
    value = meta.get(key)
    if key == 'params' and isinstance(value, dict):  # shards may differ in sample count
        value = {k: v for k, v in value.items() if k != 'samples'}
    return value


def merge_heatmaps(shards: list[Heatmap]) -> Heatmap:
    """Sum shards built with different seeds over the same robot, scene, grid and parameters."""
    if not shards:
        raise HeatmapError('nothing to merge')
    first = shards[0]
    keys = ('robot_hash', 'scene_hash', 'params')
    seeds: list[str] = []
    for i, shard in enumerate(shards):
        if shard.grid != first.grid:
            raise HeatmapError(f'shard {i}: grid {shard.grid} differs from {first.grid}')
        for key in keys:
            if _comparable(shard.meta, key) != _comparable(first.meta, key):
                raise HeatmapError(f'shard {i}: {key} differs ({shard.meta.get(key)!r} vs '
                                   f'{first.meta.get(key)!r})')
        if not np.array_equal(shard.free, first.free):
            raise HeatmapError(f'shard {i}: free-voxel masks differ')
        seeds += shard.meta.get('seeds', [])
    if len(set(seeds)) != len(seeds):
        raise HeatmapError(f'shards share seeds {seeds}: their samples would be counted '
                           'twice')
    meta = dict(first.meta)
    meta.update(
        seeds=seeds,
        valid_samples=sum(int(s.meta.get('valid_samples', 0)) for s in shards),
        candidates=sum(int(s.meta.get('candidates', 0)) for s in shards),
        build_s=sum(float(s.meta.get('build_s', 0.0)) for s in shards),
        merged_from=len(shards))
    values = np.sum([s.values for s in shards], axis=0)
    return Heatmap(first.grid, values, first.free.copy(), meta)
