"""Offline phase: the kinematic occupancy heatmap H (paper §IV-A, SPEC §2).

For ``samples`` valid configurations q (joint limits, no self collision per SRDF, no collision
with the scene E), every free voxel whose centre lies inside one of the robot's link solids at q
gets ``H[v] += w(q)`` (once per q even where links overlap), with

    w(q) = s_man(q)^gamma1 * s_clr(q)^gamma2,  s_man = m / (m + kappa),  m = sqrt(det(J J^T)),
    s_clr = min(d_clr / d_safe, 1),  d_clr = min distance between links and E.

Speed: candidate validity is checked in parallel in C++
(``pinocchio.computeCollisionsInParallel``);
links are rasterized with precomputed look-up tables (``voxels.SolidLUT``), so a batch of
configurations costs a handful of numpy operations. Samples are split into fixed chunks, each
with its own seed stream, and chunk results are summed in chunk order: the file is identical for
a given seed whatever the number of worker processes.

File format (``.npz``, no pickle): ``format_version``, ``origin_m``, ``voxel_m``, ``shape``,
``values`` (float64 H), ``free`` (bool V_free) and ``meta_json`` (UTF-8 JSON: robot and scene
hashes, parameters, seed(s), sample counts, build time). Shards built with different seeds over
the same robot, scene and grid merge by summing.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import multiprocessing
import pathlib
import time
import zipfile
import zlib
from typing import Callable

import numba
import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.fileio import atomic_open
from advocc_ros.limits import MAX_HEATMAP_BYTES, MAX_HEATMAP_VOXELS
from advocc_ros.model.robot import RobotModel, load_robot
from advocc_ros.model.scene import Scene
from advocc_ros.model.voxels import SolidLUT, VoxelGrid, occupied_mask

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
CHUNK_SAMPLES = 1000
_GRID_SEED = 20240521  # fixed: the grid depends on robot, voxel and margin only, never the seed


class HeatmapError(ValueError):
    """A heatmap file that is corrupted, truncated, of another version or for another robot."""


@dataclasses.dataclass(frozen=True)
class HeatmapConfig:
    """Offline parameters, defaults from the paper (§V-A) and SPEC §2."""

    samples: int = 15_000
    """N_off: number of *valid* configurations."""
    voxel_m: float = 0.02
    """delta: voxel edge [m]."""
    kappa: float = 0.01
    """Manipulability saturation: s_man = m / (m + kappa)."""
    d_safe_m: float = 0.1
    """Clearance normalisation: s_clr = min(d_clr / d_safe, 1) [m]."""
    gamma_man: float = 1.0
    gamma_clr: float = 1.0
    margin_m: float = 0.1
    """Padding around the robot's swept-volume bounding box [m]."""
    robot_only: bool = False
    """Ignore the scene offline (E empty); the online phase masks the current scene."""
    lut_pitch_fraction: float = 0.25
    """Link look-up-table pitch as a fraction of the voxel edge."""

    def __post_init__(self):
        checks = {'samples': self.samples >= 1, 'voxel_m': 0.002 <= self.voxel_m <= 0.5,
                  'kappa': self.kappa > 0, 'd_safe_m': self.d_safe_m > 0,
                  'gamma_man': self.gamma_man >= 0, 'gamma_clr': self.gamma_clr >= 0,
                  'margin_m': self.margin_m >= 0,
                  'lut_pitch_fraction': 0 < self.lut_pitch_fraction <= 1}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or not np.isfinite(float(value)):
                raise ValueError(f'heatmap parameter {name}={value!r} is out of range')


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
            raise HeatmapError(f'{path}: arrays of {inflated} bytes, limit {MAX_HEATMAP_BYTES} '
                               '(MAX_HEATMAP_VOXELS)')
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError,
            NotImplementedError) as exc:
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
    except (TypeError, ValueError):
        raise HeatmapError(f'{path}: format_version is not an integer') from None
    if version != FORMAT_VERSION:
        raise HeatmapError(f'{path}: format version {version}, this advocc reads '
                           f'{FORMAT_VERSION}; rebuild it with `advocc heatmap build`')
    try:
        grid = VoxelGrid(tuple(float(v) for v in arrays['origin_m']),
                         float(arrays['voxel_m']), tuple(int(v) for v in arrays['shape']))
        meta = json.loads(arrays['meta_json'].tobytes().decode())
    except (ValueError, TypeError, UnicodeDecodeError, OverflowError) as exc:
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
    if robot_hash is not None and meta.get('robot_hash') != robot_hash:
        raise HeatmapError(f'{path}: built for robot {meta.get("robot_hash")!r} '
                           f'({meta.get("robot_urdf")}), not this robot ({robot_hash})')
    return Heatmap(grid, values, free, meta)


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


# --------------------------------------------------------------------------------------------
# Building

def workspace_grid(robot: RobotModel, voxel_m: float, margin_m: float) -> VoxelGrid:
    """Grid over the bounding box of the robot's swept volume plus a margin, snapped to voxels.

    The box is estimated from 4000 configurations of a fixed seed (every link's bounding
    sphere), so every shard of the same robot and voxel size gets the same grid.
    """
    world = CollisionWorld(robot)
    luts = [m.bounds for m in robot.link_meshes]
    rng = np.random.default_rng(_GRID_SEED)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for q in robot.sample_q(rng, 4000):
        for (b_lo, b_hi), T in zip(luts, world.link_placements(q)):
            c = T.act((b_lo + b_hi) / 2)
            r = np.linalg.norm(b_hi - b_lo) / 2
            lo, hi = np.minimum(lo, c - r), np.maximum(hi, c + r)
    lo = np.floor((lo - margin_m) / voxel_m) * voxel_m
    hi = np.ceil((hi + margin_m) / voxel_m) * voxel_m
    shape = tuple(int(round(v)) for v in (hi - lo) / voxel_m)
    return VoxelGrid(tuple(float(v) for v in lo), float(voxel_m), shape)


@numba.njit(cache=True, nogil=True)
def _accumulate(H, stamp, free, grid_origin, voxel, grid_shape, R, t, weights, sample0,
                lut_data, lut_offset, lut_shape, lut_origin, lut_pitch, box_lo, box_hi):
    """Add ``weights[s]`` to every free voxel whose centre is inside a link at sample ``s``.

    R (n, L, 3, 3), t (n, L, 3): ``T_base_link`` per sample and link. Each link is scanned
    over the voxels of its rotated bounding box only; a voxel is counted once per sample even
    where links overlap (``stamp`` remembers the last sample that added to it).
    """
    ny, nz = grid_shape[1], grid_shape[2]
    for s in range(R.shape[0]):
        sid = sample0 + s
        w = weights[s]
        for li in range(R.shape[1]):
            r = R[s, li]
            lo = np.empty(3, np.int64)
            hi = np.empty(3, np.int64)
            for a in range(3):
                c = t[s, li, a]
                e = 0.0
                for b in range(3):
                    mid = 0.5 * (box_lo[li, b] + box_hi[li, b])
                    c += r[a, b] * mid
                    e += abs(r[a, b]) * 0.5 * (box_hi[li, b] - box_lo[li, b])
                # voxel centres origin + (i + 0.5) voxel inside [c - e, c + e]
                lo[a] = max(0, int(np.ceil((c - e - grid_origin[a]) / voxel - 0.5)))
                hi[a] = min(grid_shape[a] - 1,
                            int(np.floor((c + e - grid_origin[a]) / voxel - 0.5)))
            sx, sy, sz = lut_shape[li, 0], lut_shape[li, 1], lut_shape[li, 2]
            off = lut_offset[li]
            inv = 1.0 / lut_pitch
            for i in range(lo[0], hi[0] + 1):
                px = grid_origin[0] + (i + 0.5) * voxel - t[s, li, 0]
                for j in range(lo[1], hi[1] + 1):
                    py = grid_origin[1] + (j + 0.5) * voxel - t[s, li, 1]
                    for k in range(lo[2], hi[2] + 1):
                        pz = grid_origin[2] + (k + 0.5) * voxel - t[s, li, 2]
                        # local = R^T p, then look-up-table cell
                        gx = int(np.floor((r[0, 0] * px + r[1, 0] * py + r[2, 0] * pz
                                           - lut_origin[li, 0]) * inv))
                        if gx < 0 or gx >= sx:
                            continue
                        gy = int(np.floor((r[0, 1] * px + r[1, 1] * py + r[2, 1] * pz
                                           - lut_origin[li, 1]) * inv))
                        if gy < 0 or gy >= sy:
                            continue
                        gz = int(np.floor((r[0, 2] * px + r[1, 2] * py + r[2, 2] * pz
                                           - lut_origin[li, 2]) * inv))
                        if gz < 0 or gz >= sz:
                            continue
                        if lut_data[off + (gx * sy + gy) * sz + gz]:
                            v = (i * ny + j) * nz + k
                            if free[v] and stamp[v] != sid:
                                stamp[v] = sid
                                H[v] += w
    return H


class _LinkTables:
    """All link look-up tables packed into flat arrays for the compiled kernel."""

    def __init__(self, robot: RobotModel, lut_pitch_m: float):
        luts = [SolidLUT.from_mesh(m, lut_pitch_m) for m in robot.link_meshes]
        self.pitch = float(lut_pitch_m)
        self.shape = np.array([lut.filled.shape for lut in luts], dtype=np.int64)
        sizes = self.shape.prod(axis=1)
        self.offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.data = np.concatenate([lut.filled.ravel() for lut in luts]).astype(np.uint8)
        self.origin = np.array([lut.origin_m for lut in luts])
        self.box_lo = np.array([m.bounds[0] for m in robot.link_meshes])
        self.box_hi = np.array([m.bounds[1] for m in robot.link_meshes])


def _placement_arrays(world: CollisionWorld, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, L, 3, 3) and translations (n, L, 3) of every link for each q."""
    R = np.empty((len(Q), world.n_links, 3, 3))
    t = np.empty((len(Q), world.n_links, 3))
    for s, q in enumerate(Q):
        for li, T in enumerate(world.link_placements(q)):
            R[s, li] = T.rotation
            t[s, li] = T.translation
    return R, t


def sample_weights(robot: RobotModel, world: CollisionWorld, Q: np.ndarray,
                   cfg: HeatmapConfig) -> np.ndarray:
    """w(q) for each valid q; clearance distances only where a link is within d_safe."""
    data = robot.create_data()
    s_man = np.empty(len(Q))
    for i, q in enumerate(Q):
        m = robot.manipulability(q, data)
        s_man[i] = m / (m + cfg.kappa)
    s_clr = np.ones(len(Q))
    if world.shapes:
        near = world.near_scene_batch(Q, cfg.d_safe_m)
        for i in np.flatnonzero(near):
            s_clr[i] = min(max(world.scene_distance(Q[i]), 0.0) / cfg.d_safe_m, 1.0)
    return s_man ** cfg.gamma_man * s_clr ** cfg.gamma_clr


# Set by build_heatmap before forking workers, so they inherit the tables instead of rebuilding.
_CONTEXT: dict = {}


def _build_chunk(args) -> tuple[np.ndarray, int, int]:
    """Accumulate one chunk: (H flat, valid samples, candidates drawn)."""
    chunk, seed_seq, n_valid = args
    robot, world, tables = _CONTEXT['robot'], _CONTEXT['world'], _CONTEXT['tables']
    grid, free_flat, cfg = _CONTEXT['grid'], _CONTEXT['free'], _CONTEXT['cfg']
    rng = np.random.default_rng(seed_seq)
    H = np.zeros(grid.size)
    stamp = np.full(grid.size, -1, dtype=np.int64)
    done = drawn = 0
    while done < n_valid:
        Q = robot.sample_q(rng, 512)
        drawn += len(Q)
        Q = Q[~world.collisions_batch(Q, threads=1)][:n_valid - done]
        if done == 0 and drawn >= 50_000 and len(Q) == 0:
            raise RuntimeError('no valid configuration in 50,000 draws: is the robot inside '
                               'the scene?')
        R, t = _placement_arrays(world, Q)
        _accumulate(H, stamp, free_flat, np.asarray(grid.origin_m), grid.voxel_m,
                    np.asarray(grid.shape, dtype=np.int64), R, t,
                    sample_weights(robot, world, Q, cfg), done, tables.data, tables.offset,
                    tables.shape, tables.origin, tables.pitch, tables.box_lo, tables.box_hi)
        done += len(Q)
    return H, done, drawn


def build_heatmap(scene: Scene, cfg: HeatmapConfig = HeatmapConfig(), seed: int = 0,
                  workers: int = 1, progress: Callable[[int], None] | None = None,
                  shard: tuple[int, int] = (0, 1)) -> Heatmap:
    """Build H for ``scene``'s robot and objects (objects ignored when ``cfg.robot_only``).

    ``shard=(i, k)`` builds only chunks ``i, i+k, i+2k, ...`` of the seed's sample stream, so
    k machines can each build one shard and ``merge_heatmaps`` reproduces the full build.
    ``progress(n)`` is called with the number of valid samples finished after each chunk.
    """
    index, count = shard
    if not (0 <= index < count):
        raise ValueError(f'shard {index}/{count}: need 0 <= index < count')
    t0 = time.perf_counter()
    robot = load_robot(scene.robot)
    shapes = [] if cfg.robot_only else scene.shapes
    grid = workspace_grid(robot, cfg.voxel_m, cfg.margin_m)
    free = ~occupied_mask(grid, shapes)
    sizes = [CHUNK_SAMPLES] * (cfg.samples // CHUNK_SAMPLES)
    if cfg.samples % CHUNK_SAMPLES:
        sizes.append(cfg.samples % CHUNK_SAMPLES)
    seqs = np.random.SeedSequence(seed).spawn(len(sizes))  # chunk i always gets stream i
    _CONTEXT.update(robot=robot, world=CollisionWorld(robot, shapes), grid=grid,
                    free=free.ravel(), cfg=cfg,
                    tables=_LinkTables(robot, cfg.voxel_m * cfg.lut_pitch_fraction))
    tasks = [(i, s, n) for i, (s, n) in enumerate(zip(seqs, sizes))][index::count]
    if not tasks:
        raise ValueError(f'shard {index}/{count} is empty: {len(sizes)} chunks of '
                         f'{CHUNK_SAMPLES} samples')
    if workers > 1:
        # fork: workers inherit loaded modules (spawn would re-import pinocchio, ~1 s each).
        with multiprocessing.get_context('fork').Pool(min(workers, len(tasks))) as pool:
            results = []
            for res in pool.imap(_build_chunk, tasks):
                results.append(res)
                if progress:
                    progress(res[1])
    else:
        results = []
        for task in tasks:
            results.append(_build_chunk(task))
            if progress:
                progress(results[-1][1])
    H = np.zeros(grid.size)
    for chunk_H, _, _ in results:  # chunk order: identical sums for any worker count
        H += chunk_H
    build_s = time.perf_counter() - t0
    meta = {
        'robot_hash': robot.hash, 'robot_urdf': scene.robot.urdf,
        'robot_joints': list(robot.joint_names), 'robot_links': list(robot.link_names),
        'scene_hash': None if cfg.robot_only else scene.objects_hash(),
        'scene_name': None if cfg.robot_only else scene.name,
        'params': dataclasses.asdict(cfg),
        'seeds': [str(seed) if count == 1 else f'{seed}:{index}/{count}'],
        'valid_samples': int(sum(r[1] for r in results)),
        'candidates': int(sum(r[2] for r in results)),
        'build_s': round(build_s, 3), 'workers': workers,
        'created_unix': round(time.time(), 3),
    }
    log.info('heatmap: %d valid of %d candidates in %.2f s', meta['valid_samples'],
             meta['candidates'], build_s)
    return Heatmap(grid, H.reshape(grid.shape), free, meta)
