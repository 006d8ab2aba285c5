"""Offline phase: the kinematic occupancy heatmap H (paper §IV-A; docs/design.md).

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

The result is a :class:`advocc_ros.heatmap.store.Heatmap` (file format and merging there).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import multiprocessing
import pathlib
import signal
import threading
import time
import zipfile
from typing import Callable

import numpy as np

from advocc_ros import kernels
from advocc_ros.heatmap.config import HeatmapConfig
from advocc_ros.heatmap.store import Heatmap
from advocc_ros.fileio import atomic_open
from advocc_ros.model.cache import BoundedCache, disk_cache_dir
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, load_robot
from advocc_ros.model.scene import Scene
from advocc_ros.model.voxels import SolidLUT, VoxelGrid, occupied_mask

log = logging.getLogger(__name__)

CHUNK_SAMPLES = 1000
_GRID_SEED = 20240521  # fixed: the grid depends on robot, voxel and margin only, never the seed


# --------------------------------------------------------------------------------------------
# Building

def workspace_grid(robot: RobotModel, voxel_m: float, margin_m: float) -> VoxelGrid:
    """Grid over the bounding box of the robot's swept volume plus a margin, snapped to voxels.

    The box is estimated from 4000 configurations of a fixed seed (every link's bounding
    sphere), so every shard of the same robot and voxel size gets the same grid.
    """
    world = CollisionWorld(robot)
    luts = list(zip(*robot.link_bounds_m))
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


class LinkTables:
    """All link look-up tables packed into flat arrays for the compiled kernels."""

    ARRAYS = ('shape', 'offset', 'data', 'origin', 'box_lo', 'box_hi')
    """What a table file holds besides the pitch."""

    def __init__(self, pitch_m: float, shape: np.ndarray, offset: np.ndarray, data: np.ndarray,
                 origin: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray):
        self.pitch = float(pitch_m)
        self.shape, self.offset, self.data = shape, offset, data
        self.origin, self.box_lo, self.box_hi = origin, box_lo, box_hi

    @classmethod
    def build(cls, robot: RobotModel, lut_pitch_m: float) -> 'LinkTables':
        luts = [SolidLUT.from_mesh(m, lut_pitch_m) for m in robot.link_meshes]
        shape = np.array([lut.filled.shape for lut in luts], dtype=np.int64)
        sizes = shape.prod(axis=1)
        return cls(lut_pitch_m, shape,
                   np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
                   np.concatenate([lut.filled.ravel() for lut in luts]).astype(np.uint8),
                   np.array([lut.origin_m for lut in luts]), *robot.link_bounds_m)

    @classmethod
    def read(cls, path: pathlib.Path, n_links: int, pitch_m: float) -> 'LinkTables':
        """Tables saved by :meth:`write`; ``ValueError`` unless they fit ``n_links`` links."""
        try:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {name: np.asarray(npz[name]) for name in cls.ARRAYS + ('pitch',)}
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
            raise ValueError(f'{path}: not a link table file ({exc})') from exc
        shape, offset, data = arrays['shape'], arrays['offset'], arrays['data']
        fits = (shape.shape == (n_links, 3) and offset.shape == (n_links,)
                and shape.dtype == offset.dtype == np.int64 and data.dtype == np.uint8
                and np.all(shape > 0) and np.array_equal(
                    offset, np.concatenate([[0], np.cumsum(shape.prod(axis=1))[:-1]]))
                and data.shape == (int(shape.prod(axis=1).sum()),)
                and all(arrays[k].shape == (n_links, 3) and np.all(np.isfinite(arrays[k]))
                        for k in ('origin', 'box_lo', 'box_hi'))
                and arrays['pitch'].shape == () and float(arrays['pitch']) == pitch_m)
        if not fits:
            raise ValueError(f'{path}: link tables of another robot or pitch, or damaged')
        return cls(pitch_m, shape, offset, data, arrays['origin'].astype(float),
                   arrays['box_lo'].astype(float), arrays['box_hi'].astype(float))

    def write(self, path: pathlib.Path) -> None:
        with atomic_open(path, 'wb') as handle:
            np.savez_compressed(handle, pitch=self.pitch,
                                **{name: getattr(self, name) for name in self.ARRAYS})

    def rasterize(self, mask: np.ndarray, origin_m: np.ndarray, voxel_m: float,
                  R: np.ndarray, t: np.ndarray, links=None) -> np.ndarray:
        """``mask`` (a grid of pitch ``voxel_m`` with its corner at ``origin_m``) |= voxel
        centres inside ``links`` (default all) placed at ``T_base_link`` = (R (L, 3, 3),
        t (L, 3)), or at each of several configurations (R (n, L, 3, 3), t (n, L, 3))."""
        links = np.arange(len(self.shape)) if links is None else np.asarray(links, np.int64)
        R, t = (R[None], t[None]) if np.ndim(R) == 3 else (R, t)
        # The heatmap kernel: samples 1..n (so zeroed stamps never match) of weight 1.
        hits = np.zeros(mask.size)
        kernels.accumulate(hits, np.zeros(mask.size, np.int64), np.ones(mask.size, np.bool_),
                           origin_m, voxel_m, mask.shape, R[:, links], t[:, links],
                           np.ones(len(R)), 1, self.kernel_tables(links))
        mask |= hits.reshape(mask.shape) > 0
        return mask

    def kernel_tables(self, links: np.ndarray | None = None) -> kernels.Tables:
        """The tables of ``links`` (default all) as the kernels read them."""
        return kernels.Tables(self.data, self.offset, self.shape, self.origin, self.pitch,
                              self.box_lo, self.box_hi, links)


LINK_TABLES: BoundedCache = BoundedCache('link look-up tables', 8)
"""(robot hash, pitch) -> LinkTables, this process's copies (cleared, the next call reads the
disk cache, as another process would)."""


def link_tables(robot: RobotModel, pitch_m: float) -> LinkTables:
    """The robot's tables at ``pitch_m``: built once per process (Panda at 5 mm: < 0.1 s, and
    0.3 s to import trimesh), or read from the disk cache where an earlier process left them."""
    return LINK_TABLES.get_or_make((robot.hash, round(pitch_m, 9)),
                                   lambda: _tables_from_disk_or_built(robot, pitch_m))


def _tables_from_disk_or_built(robot: RobotModel, pitch_m: float) -> LinkTables:
    path = _tables_file(robot, pitch_m)
    if path is not None and path.is_file():
        try:
            return LinkTables.read(path, len(robot.link_names), pitch_m)
        except ValueError as exc:
            log.warning('link tables: %s (building them again)', exc)
    tables = LinkTables.build(robot, pitch_m)
    if path is not None:
        try:
            tables.write(path)
        except OSError as exc:  # a read-only cache must not fail the caller
            log.warning('link tables: cannot write %s (%s)', path, exc)
    return tables


def _tables_file(robot: RobotModel, pitch_m: float) -> pathlib.Path | None:
    """The tables' file in the disk cache, named by the robot, the pitch and its mesh files'
    sizes and times (an edited mesh makes new tables)."""
    root = disk_cache_dir()
    if root is None:
        return None
    meshes = [pathlib.Path(g.meshPath) for g in robot.collision_model.geometryObjects]
    stamps = [(str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in meshes if p.is_file()]
    key = hashlib.sha256(repr((robot.hash, round(pitch_m, 9), stamps)).encode()).hexdigest()
    return root / 'link_tables' / f'{key[:16]}.npz'


def placement_arrays(world: CollisionWorld, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, L, 3, 3) and translations (n, L, 3) of every link for each q."""
    H = world.link_transforms(Q)
    return np.ascontiguousarray(H[:, :, :3, :3]), np.ascontiguousarray(H[:, :, :3, 3])


def sample_weights(robot: RobotModel, world: CollisionWorld, Q: np.ndarray,
                   cfg: HeatmapConfig, threads: int = 1) -> np.ndarray:
    """w(q) for each valid q; clearance distances only where a link is within d_safe (found by
    one batched collision pass on ``threads`` threads)."""
    data = robot.create_data()
    s_man = np.empty(len(Q))
    for i, q in enumerate(Q):
        m = robot.manipulability(q, data)
        s_man[i] = m / (m + cfg.kappa)
    s_clr = np.ones(len(Q))
    if world.shapes:
        near = np.flatnonzero(world.near_scene_batch(Q, cfg.d_safe_m, threads))
        d = world.scene_clearances(Q[near], cfg.d_safe_m)
        s_clr[near] = np.minimum(np.maximum(d, 0.0) / cfg.d_safe_m, 1.0)
    return s_man ** cfg.gamma_man * s_clr ** cfg.gamma_clr


def _worker_signals() -> None:
    """Pool workers must not run the parent's signal handlers (the orchestrator's raise
    ``Interrupted``: a traceback per worker when the pool ends it). SIGTERM (how the pool ends
    its workers) kills; SIGINT is the parent's to handle."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# Set by _run_chunks before forking workers, so they inherit the tables instead of rebuilding;
# the lock keeps a second build in another thread from swapping it under the first.
_CONTEXT: dict = {}
_BUILD_LOCK = threading.Lock()


def _build_chunk(args) -> tuple[np.ndarray, int, int]:
    """Accumulate one chunk: (H flat, valid samples, candidates drawn)."""
    chunk, seed_seq, n_valid = args
    robot, world, tables = _CONTEXT['robot'], _CONTEXT['world'], _CONTEXT['tables']
    grid, free_flat, cfg = _CONTEXT['grid'], _CONTEXT['free'], _CONTEXT['cfg']
    rng = np.random.default_rng(seed_seq)
    H = np.zeros(grid.size)
    stamp = np.full(grid.size, -1, dtype=np.int64)
    packed = tables.kernel_tables()
    done = drawn = 0
    while done < n_valid:
        Q = robot.sample_q(rng, 512)
        drawn += len(Q)
        Q = Q[~world.collisions_batch(Q, threads=1)][:n_valid - done]
        if done == 0 and drawn >= 50_000 and len(Q) == 0:
            raise RuntimeError('no valid configuration in 50,000 draws: is the robot inside '
                               'the scene?')
        R, t = placement_arrays(world, Q)
        kernels.accumulate(H, stamp, free_flat, grid.origin_m, grid.voxel_m, grid.shape, R, t,
                           sample_weights(robot, world, Q, cfg), done, packed)
        done += len(Q)
    return H, done, drawn


def _run_chunks(context: dict, tasks: list, workers: int,
                progress: Callable[[int], None] | None) -> list[tuple[np.ndarray, int, int]]:
    """``_build_chunk`` of every task with ``context`` as ``_CONTEXT``, in ``workers`` forked
    processes (they inherit loaded modules; spawn would re-import pinocchio, ~1 s each)."""
    results = []
    with _BUILD_LOCK:
        _CONTEXT.clear()
        _CONTEXT.update(context)
        try:
            if workers > 1:
                with multiprocessing.get_context('fork').Pool(min(workers, len(tasks)),
                                                              _worker_signals) as pool:
                    for res in pool.imap(_build_chunk, tasks):
                        results.append(res)
                        if progress:
                            progress(res[1])
            else:
                for task in tasks:
                    results.append(_build_chunk(task))
                    if progress:
                        progress(results[-1][1])
        finally:
            _CONTEXT.clear()
    return results


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
    context = dict(robot=robot, world=CollisionWorld(robot, shapes), grid=grid,
                   free=free.ravel(), cfg=cfg,
                   tables=link_tables(robot, cfg.voxel_m * cfg.lut_pitch_fraction))
    tasks = [(i, s, n) for i, (s, n) in enumerate(zip(seqs, sizes))][index::count]
    if not tasks:
        raise ValueError(f'shard {index}/{count} is empty: {len(sizes)} chunks of '
                         f'{CHUNK_SAMPLES} samples')
    results = _run_chunks(context, tasks, workers, progress)
    H = np.zeros(grid.size)
    for chunk_H, _, _ in results:  # chunk order: identical sums for any worker count
        H += chunk_H
    build_s = time.perf_counter() - t0
    meta = {
        'robot_hash': robot.hash, 'robot_urdf': scene.robot.urdf,
        'robot': robot.spec.to_dict(),  # the identity it was built with, locked joints included
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
