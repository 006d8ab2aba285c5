"""Online phase: adversarial occupancy maximization (paper §IV-B, Algorithm 1; SPEC §3).

Given a heatmap H, the scene E, the start ``q_init`` and a goal region G, place at most M
axis-aligned boxes of edge s that cover as much heatmap mass as possible.

Search region (constraints C1-C3), all on the heatmap's voxel grid (box centres are voxel
centres, ``U(c)`` = voxels whose centres lie in the closed box):

- corridor: centre within ``r_corr`` of the segment from the tool point at ``q_init`` to the
  goal-region centre; ``H(c) > 0``; ``c`` in V_free (V_free of the file AND not inside the
  current scene: robot-only heatmaps need this, scene-conditioned ones get it for free);
- the box fits: no occupied (non-free) voxel centre inside the box, i.e. ``U(c)`` is in V_free;
- clearance ``d_safe`` from the robot body at ``q_init``, from G's position box, and from the
  hand (every link on the end-effector's joint) at one goal configuration found by a
  deterministic damped-least-squares IK from ``q_init`` to the goal centre (skipped, and
  reported, when the IK does not converge). Protecting the hand at the goal, not the whole arm,
  keeps the goal itself reachable (no trivial infeasibility) while the approach stays open to
  attack.

The voxel tests use an exact lattice "box distance transform" (distance from each candidate's
box to the nearest protected voxel centre), which can only over-estimate true clearances, so
it never drops a valid candidate; every box a method picks is then checked exactly with coal
(scene: no contact; robot at ``q_init``, goal box, hand at goal: distance >= d_safe) and a
failing candidate is discarded and the method picks again ("lazy" verification).

Greedy: box sums of the uncovered mass by separable shift-adds over a window around the
corridor; after each pick only the sums within 2k voxels of it change and are recomputed
locally. Random baseline: candidates in a seeded random order under the same constraints.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import logging
import math
import pathlib
import time
from typing import Any, Callable

import coal
import numpy as np
import pinocchio as pin

from advocc_ros.model.collision import CollisionWorld, coal_geometry
from advocc_ros.heatmap.build import Heatmap
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.scene import (GoalRegion, SceneError, SceneObject, Shape, make_box,
                              objects_from_data, objects_to_data, read_yaml, save_yaml_atomic)
from advocc_ros.model.voxels import SolidLUT, VoxelGrid, occupied_mask, points_in_shape

log = logging.getLogger(__name__)

OBSTACLES_FORMAT = 'advocc_obstacles'
OBSTACLES_VERSION = 1
_CONTACT_TOL_M = 1e-6


@dataclasses.dataclass(frozen=True)
class AttackConfig:
    """Online parameters; defaults from the paper (§V-A) and SPEC §3."""

    box_size_m: float = 0.05
    """s: edge of every adversarial box [m]."""
    corridor_radius_m: float = 0.3
    """r_corr: candidate centres lie within this distance of the start-goal segment [m]."""
    d_safe_m: float = 0.1
    """Clearance of every box from the robot at q_init and from the goal region [m]."""
    d_min_m: float = 0.05
    """Minimum distance between box centres [m]."""
    max_budget: int = 100
    """Largest budget M a request may ask for."""
    max_box_m: float = 0.5
    """Largest box edge a request may ask for [m]."""
    protect_goal_hand: bool = True
    """Also keep d_safe from the hand at an IK solution for the goal centre."""
    max_rejections: int = 500
    """Picks that fail the exact coal check before a method gives up (then PARTIAL)."""

    def __post_init__(self):
        checks = {'box_size_m': 0 < self.box_size_m <= self.max_box_m,
                  'corridor_radius_m': self.corridor_radius_m > 0,
                  'd_safe_m': self.d_safe_m >= 0, 'd_min_m': self.d_min_m >= 0,
                  'max_budget': self.max_budget >= 1, 'max_box_m': self.max_box_m > 0,
                  'max_rejections': self.max_rejections >= 0}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or not np.isfinite(float(value)):
                raise ValueError(f'attack parameter {name}={value!r} is out of range')


class AttackStatus(enum.Enum):
    """Outcome of an attack request; errors are data (the node maps them to ErrorCodes)."""

    SUCCESS = 'success'
    PARTIAL = 'partial'                      # fewer than M boxes fit the search region
    INVALID_REQUEST = 'invalid_request'      # budget, box size, non-finite numbers
    UNKNOWN_METHOD = 'unknown_method'
    INVALID_START = 'invalid_start'          # wrong joints, out of limits
    START_IN_COLLISION = 'start_in_collision'
    INVALID_GOAL = 'invalid_goal'            # empty or malformed goal region
    INVALID_LINK = 'invalid_link'            # goal link not in the robot
    ROBOT_MISMATCH = 'robot_mismatch'        # heatmap built for another robot

    @property
    def ok(self) -> bool:
        return self in (AttackStatus.SUCCESS, AttackStatus.PARTIAL)


@dataclasses.dataclass(frozen=True)
class AttackResult:
    """Obstacles placed by one attack, the mass each covered, and what it cost."""

    status: AttackStatus
    message: str = ''
    obstacles: tuple[SceneObject, ...] = ()
    """Boxes ``adv_0``, ``adv_1``, ... in pick order (robot base frame)."""
    masses: tuple[float, ...] = ()
    """Heatmap mass each box added to the coverage (marginal, in pick order)."""
    total_mass: float = 0.0
    compute_s: float = 0.0
    """Core time: search region, selection and exact checks (no file or message I/O)."""
    method: str = ''
    budget: int = 0
    box_size_m: float = 0.0
    stats: dict = dataclasses.field(default_factory=dict)
    """Diagnostics: candidate counts per filter, rejected picks, goal IK outcome."""

    @property
    def centers_m(self) -> np.ndarray:
        return np.array([o.shapes[0].pose.position_m for o in self.obstacles]).reshape(-1, 3)

    def to_json(self) -> dict:
        return {'status': self.status.value, 'message': self.message, 'method': self.method,
                'budget': self.budget, 'box_size_m': self.box_size_m,
                'obstacles': objects_to_data(self.obstacles),
                'masses': [float(m) for m in self.masses], 'total_mass': float(self.total_mass),
                'compute_ms': round(self.compute_s * 1e3, 3), 'stats': self.stats}


class AttackError(ValueError):
    """A request that cannot be attacked; ``status`` says why."""

    def __init__(self, status: AttackStatus, message: str):
        super().__init__(message)
        self.status = status


# --------------------------------------------------------------------------------------------
# Grid helpers (all vectorized; no Python loop over voxels)

def box_half_voxels(box_size_m: float, voxel_m: float) -> int:
    """k such that U(c) is the (2k+1)^3 cube of voxels whose centres lie in the box."""
    return int(math.floor(box_size_m / 2 / voxel_m + 1e-9))


def _shift_add(a: np.ndarray, out: np.ndarray, offset: int, axis: int, op) -> None:
    """``out[i] = op(out[i], a[i - offset])`` along ``axis`` where both indices are valid."""
    n = a.shape[axis]
    if abs(offset) >= n:
        return
    dst = [slice(None)] * 3
    src = [slice(None)] * 3
    if offset > 0:
        dst[axis], src[axis] = slice(offset, None), slice(None, n - offset)
    else:
        dst[axis], src[axis] = slice(None, n + offset), slice(-offset, None)
    op(out[tuple(dst)], a[tuple(src)], out=out[tuple(dst)])


def box_sum(values: np.ndarray, k: int) -> np.ndarray:
    """Sum of ``values`` over the (2k+1)^3 cube around each voxel (zero outside the array).

    Separable shift-adds, not an integral volume: no cancellation, and a sub-block gives
    bit-identical sums to the full array, so local updates match a full recomputation.
    """
    out = np.asarray(values, dtype=np.float64)
    for axis in range(3):
        acc = out.copy()
        for o in range(1, k + 1):
            _shift_add(out, acc, o, axis, np.add)
            _shift_add(out, acc, -o, axis, np.add)
        out = acc
    return out


def box_distance(mask: np.ndarray, voxel_m: float, half_m: float, max_m: float,
                 crop: tuple[slice, slice, slice] | None = None) -> np.ndarray:
    """Distance [m] from the closed box (half-edge ``half_m``) centred on each voxel centre to
    the nearest True voxel centre of ``mask``; ``inf`` beyond ``max_m``. ``crop``: only this
    part of the output is wanted (the input around it still counts).

    Exact on the lattice (float32): the squared distance is a sum of per-axis costs
    ``max(|dx| - half, 0)^2``, so three 1-D min-convolutions (generalized distance transform)
    give it, each over the few offsets that can stay within ``max_m``; each pass then drops
    the rows of its axis outside ``crop``.
    """
    reach = int(math.ceil((max_m + half_m) / voxel_m))
    out = np.where(mask, np.float32(0), np.float32(np.inf))
    for axis in range(3):
        acc = out.copy()
        tmp = np.empty_like(out)
        for o in range(1, min(reach, out.shape[axis] - 1) + 1):
            cost = max(o * voxel_m - half_m, 0.0) ** 2
            if cost > max_m ** 2:
                break
            n = out.shape[axis]
            for dst, src in ((slice(o, None), slice(None, n - o)),
                             (slice(None, n - o), slice(o, None))):
                d = tuple(dst if a == axis else slice(None) for a in range(3))
                s = tuple(src if a == axis else slice(None) for a in range(3))
                np.add(out[s], np.float32(cost), out=tmp[d])
                np.minimum(acc[d], tmp[d], out=acc[d])
        out = acc
        if crop is not None:
            out = out[tuple(crop[a] if a == axis else slice(None) for a in range(3))]
    return np.sqrt(out, dtype=np.float64)


def _ball_offsets(radius_vox: float) -> np.ndarray:
    """Integer offsets (n, 3) strictly closer than ``radius_vox`` to the origin."""
    r = int(math.ceil(radius_vox))
    g = np.arange(-r, r + 1)
    off = np.stack(np.meshgrid(g, g, g, indexing='ij'), -1).reshape(-1, 3)
    return off[np.einsum('ij,ij->i', off, off) < radius_vox ** 2 - 1e-9]


# --------------------------------------------------------------------------------------------
# Coverage selection on arrays (shared by every method; tested against brute force)

@dataclasses.dataclass
class _Coverage:
    """Uncovered mass, its box sums and the live candidate mask over one window."""

    weights: np.ndarray
    """(wx, wy, wz) mass not yet covered."""
    candidates: np.ndarray
    """(wx, wy, wz) bool, live candidates."""
    k: int
    d_min_vox: float

    def __post_init__(self):
        self.weights = np.array(self.weights, dtype=np.float64)
        self.candidates = np.array(self.candidates, dtype=bool)
        self.sums = box_sum(self.weights, self.k)
        self._drop = _ball_offsets(self.d_min_vox) if self.d_min_vox > 0 else np.zeros((1, 3),
                                                                                        int)

    def _block(self, c: np.ndarray, r: int) -> tuple[slice, ...]:
        return tuple(slice(max(c[a] - r, 0), min(c[a] + r + 1, self.weights.shape[a]))
                     for a in range(3))

    def cover(self, c: np.ndarray) -> float:
        """Cover U(c), drop candidates within d_min of c; return the mass newly covered."""
        k = self.k
        mass = float(self.sums[tuple(c)])
        self.weights[self._block(c, k)] = 0.0
        # Sums change only within 2k of c; recompute them from a block padded by k.
        outer = self._block(c, 3 * k)
        inner = self._block(c, 2 * k)
        local = box_sum(self.weights[outer], k)
        rel = tuple(slice(i.start - o.start, i.stop - o.start) for i, o in zip(inner, outer))
        self.sums[inner] = local[rel]
        idx = c + self._drop
        idx = idx[np.all((idx >= 0) & (idx < self.weights.shape), axis=1)]
        self.candidates[idx[:, 0], idx[:, 1], idx[:, 2]] = False
        return mass


Accept = Callable[[np.ndarray], bool]
"""Exact check of a candidate (window index (3,)); False discards it."""


def greedy_cover(weights: np.ndarray, candidates: np.ndarray, k: int, budget: int,
                 d_min_vox: float, accept: Accept | None = None, max_rejections: int = 500
                 ) -> tuple[list[tuple[np.ndarray, float]], int]:
    """Algorithm 1 on arrays: up to ``budget`` (index, marginal mass) picks, and rejections.

    ``U(c)`` is the (2k+1)^3 cube around index c; picks are >= ``d_min_vox`` voxels apart.
    Ties go to the first index in C order, so the result is deterministic.
    """
    if not np.any(candidates):
        return [], 0
    cov = _Coverage(weights, candidates, k, d_min_vox)
    picks, rejected = [], 0
    score = np.where(cov.candidates, cov.sums, -np.inf)
    while len(picks) < budget:
        flat = int(np.argmax(score))
        if score.flat[flat] == -np.inf:
            break
        c = np.array(np.unravel_index(flat, score.shape))
        if accept is not None and not accept(c):
            cov.candidates[tuple(c)] = False
            score.flat[flat] = -np.inf
            rejected += 1
            if rejected > max_rejections:
                log.warning('greedy: %d picks failed the exact check; giving up', rejected)
                break
            continue
        picks.append((c, cov.cover(c)))
        region = cov._block(c, max(2 * k, int(math.ceil(d_min_vox))))
        score[region] = np.where(cov.candidates[region], cov.sums[region], -np.inf)
    return picks, rejected


def random_cover(weights: np.ndarray, candidates: np.ndarray, k: int, budget: int,
                 d_min_vox: float, rng: np.random.Generator, accept: Accept | None = None,
                 max_rejections: int = 500) -> tuple[list[tuple[np.ndarray, float]], int]:
    """Random baseline: candidates uniformly at random (without replacement) under the same
    constraints as :func:`greedy_cover`; masses are the marginal coverage, as for greedy."""
    cov = _Coverage(weights, candidates, k, d_min_vox)
    order = rng.permutation(np.flatnonzero(cov.candidates))
    picks, rejected = [], 0
    for flat in order:
        if len(picks) >= budget:
            break
        c = np.array(np.unravel_index(int(flat), cov.candidates.shape))
        if not cov.candidates[tuple(c)]:
            continue
        if accept is not None and not accept(c):
            cov.candidates[tuple(c)] = False
            rejected += 1
            if rejected > max_rejections:
                break
            continue
        picks.append((c, cov.cover(c)))
    return picks, rejected


# --------------------------------------------------------------------------------------------
# The task-level search region

_LUT_CACHE: dict[tuple[str, float], list[SolidLUT]] = {}


def link_luts(robot: RobotModel, pitch_m: float) -> list[SolidLUT]:
    """Solid look-up tables of the robot's collision geometries (cached; ~0.5 s the first time)."""
    key = (robot.hash, round(pitch_m, 9))
    if key not in _LUT_CACHE:
        _LUT_CACHE[key] = [SolidLUT.from_mesh(m, pitch_m) for m in robot.link_meshes]
    return _LUT_CACHE[key]


def robot_occupancy(robot: RobotModel, placements: list[pin.SE3], grid: VoxelGrid,
                    lo: np.ndarray, hi: np.ndarray, links: list[int] | None = None
                    ) -> np.ndarray:
    """bool mask of the window ``[lo, hi)`` of ``grid``: voxel centres inside the robot's
    link solids at ``placements`` (``T_base_geom`` per collision geometry)."""
    luts = link_luts(robot, grid.voxel_m / 4)
    mask = np.zeros(tuple(hi - lo), dtype=bool)
    for li in (range(len(luts)) if links is None else links):
        lut, T = luts[li], placements[li]
        center = T.act(lut.center_m)
        i0 = np.maximum(grid.index_of(center - lut.half_diagonal_m), lo)
        i1 = np.minimum(grid.index_of(center + lut.half_diagonal_m) + 1, hi)
        if np.any(i1 <= i0):
            continue
        idx = np.stack(np.meshgrid(*[np.arange(i0[a], i1[a]) for a in range(3)],
                                   indexing='ij'), -1)
        local = (grid.centers(idx) - T.translation) @ T.rotation
        mask[i0[0] - lo[0]:i1[0] - lo[0], i0[1] - lo[1]:i1[1] - lo[1],
             i0[2] - lo[2]:i1[2] - lo[2]] |= lut.contains(local)
    return mask


def goal_configuration(robot: RobotModel, goal: GoalRegion, q_init: np.ndarray,
                       iterations: int = 200) -> np.ndarray | None:
    """One configuration whose tool point is at the goal centre (damped least squares from
    ``q_init``, joint limits clipped), or ``None`` if it does not converge into G.

    Deterministic and cheap (~ms): it only decides which hand pose to keep clear of boxes.
    """
    model = robot.model
    data = model.createData()
    fid = model.getFrameId(goal.link)
    T_des = goal.center.to_se3() * goal.tool_offset.to_se3().inverse()  # T_base_link wanted
    q = np.array(q_init, dtype=float)
    for _ in range(iterations):
        pin.framesForwardKinematics(model, data, q)
        iMd = data.oMf[fid].actInv(T_des)
        err = pin.log6(iMd).vector
        if np.linalg.norm(err) < 1e-4:
            break
        J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
        J = -pin.Jlog6(iMd.inverse()) @ J
        v = -J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), err)
        q = np.clip(pin.integrate(model, q, v * 0.5), robot.lower, robot.upper)
    pin.framesForwardKinematics(model, data, q)
    if goal.contains(data.oMf[fid] * goal.tool_offset.to_se3()):
        return q
    return None


@dataclasses.dataclass
class SearchRegion:
    """Candidates and masses over a window ``[lo, hi)`` of the heatmap grid, plus the exact
    checker for boxes. Build it with :func:`search_region`."""

    grid: VoxelGrid
    lo: np.ndarray
    hi: np.ndarray
    weights: np.ndarray
    """(window) H on the current V_free (0 elsewhere)."""
    candidates: np.ndarray
    """(window) bool: centres passing every voxel test."""
    k: int
    box_size_m: float
    d_min_m: float
    checks: list[tuple[coal.CollisionGeometry, coal.Transform3s, float, str]]
    """Exact tests: (geometry, placement, minimum distance [m], what) a box must keep."""
    stats: dict

    def center_m(self, c: np.ndarray) -> np.ndarray:
        return self.grid.centers(np.asarray(c) + self.lo)

    def box_violation(self, center_m: np.ndarray) -> str | None:
        """What an axis-aligned box at ``center_m`` is too close to (exact, coal), or None."""
        box = coal.Box(*([self.box_size_m] * 3))
        tf = coal.Transform3s(np.eye(3), np.asarray(center_m, dtype=float))
        req, res = coal.DistanceRequest(), coal.DistanceResult()
        for geom, placement, min_m, what in self.checks:
            res.clear()
            if coal.distance(box, tf, geom, placement, req, res) < min_m:
                return what
        return None

    def accept(self, c: np.ndarray) -> bool:
        what = self.box_violation(self.center_m(c))
        if what is not None:
            log.debug('candidate %s rejected by the exact check: %s', c.tolist(), what)
        return what is None


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def _tool_point(robot: RobotModel, q: np.ndarray, goal: GoalRegion) -> np.ndarray:
    data = robot.create_data()
    pin.framesForwardKinematics(robot.model, data, q)
    T = data.oMf[robot.model.getFrameId(goal.link)] * goal.tool_offset.to_se3()
    return np.array(T.translation)


def search_region(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...],
                  q_init: np.ndarray, goal: GoalRegion, cfg: AttackConfig = AttackConfig(),
                  box_size_m: float | None = None) -> SearchRegion:
    """Candidate centres X (Algorithm 1, lines 1-2) for one task; see the module docstring."""
    grid = heatmap.grid
    s = cfg.box_size_m if box_size_m is None else float(box_size_m)
    half = s / 2
    k = box_half_voxels(s, grid.voxel_m)
    shapes = [sh for o in objects for sh in o.shapes]
    x_start = _tool_point(robot, q_init, goal)
    x_goal = np.array(goal.center.position_m)
    stats: dict[str, Any] = {'x_start_m': x_start.round(4).tolist(),
                             'x_goal_m': x_goal.round(4).tolist(), 'k_voxels': k}

    # Window: corridor bounding box (candidate centres), padded for the box and distance tests.
    reach = max(cfg.d_safe_m, _CONTACT_TOL_M) + half
    pad = int(math.ceil(reach / grid.voxel_m)) + k + 1
    c_lo = grid.index_of(np.minimum(x_start, x_goal) - cfg.corridor_radius_m)
    c_hi = grid.index_of(np.maximum(x_start, x_goal) + cfg.corridor_radius_m) + 1
    shape = np.asarray(grid.shape)
    lo = np.clip(c_lo - pad, 0, shape)
    hi = np.clip(c_hi + pad, 0, shape)
    if np.any(hi <= lo):
        empty = np.zeros((0, 0, 0))
        stats['candidates'] = 0
        return SearchRegion(grid, lo, lo, empty, empty.astype(bool), k, s, cfg.d_min_m, [],
                            stats)
    win = tuple(slice(lo[a], hi[a]) for a in range(3))
    sub = VoxelGrid(tuple(grid.centers(lo) - grid.voxel_m / 2), grid.voxel_m, tuple(hi - lo))

    free = heatmap.free[win] & ~_occupied(sub, shapes)
    weights = np.where(free, heatmap.values[win], 0.0)
    in_window = np.zeros(free.shape, dtype=bool)
    crop = tuple(slice(max(c_lo[a] - lo[a], 0), max(c_hi[a] - lo[a], 0)) for a in range(3))
    in_window[crop] = True
    cand = in_window & free & (weights > 0)
    stats['free_positive'] = int(cand.sum())
    idx = np.argwhere(cand)
    far = _segment_distance(sub.centers(idx), x_start, x_goal) > cfg.corridor_radius_m
    cand[tuple(idx[far].T)] = False
    stats['corridor'] = int(cand.sum())
    # The box fits: no non-free voxel centre inside it (U(c) in V_free).
    cand[crop] &= box_distance(~free, grid.voxel_m, half, _CONTACT_TOL_M, crop) > 0
    stats['box_fits'] = int(cand.sum())

    # Clearance from the robot at q_init (+ the hand at a goal configuration).
    world = CollisionWorld(robot)
    placements = [pin.SE3(T) for T in world.link_placements(q_init)]
    protected = robot_occupancy(robot, placements, grid, lo, hi)
    checks = [(g.geometry, _tf(T), cfg.d_safe_m, f'robot link {g.name} at q_init')
              for g, T in zip(world.geom_model.geometryObjects[:world.n_links], placements)]
    q_goal = goal_configuration(robot, goal, q_init) if cfg.protect_goal_hand else None
    stats['goal_ik'] = None if not cfg.protect_goal_hand else q_goal is not None
    if q_goal is not None:
        joint = robot.model.frames[robot.model.getFrameId(goal.link)].parentJoint
        hand = [i for i, g in enumerate(world.geom_model.geometryObjects[:world.n_links])
                if g.parentJoint == joint]
        goal_placements = [pin.SE3(T) for T in world.link_placements(q_goal)]
        protected |= robot_occupancy(robot, goal_placements, grid, lo, hi, hand)
        checks += [(world.geom_model.geometryObjects[i].geometry, _tf(goal_placements[i]),
                    cfg.d_safe_m, f'hand {world.geom_model.geometryObjects[i].name} at goal')
                   for i in hand]
        stats['q_goal'] = np.round(q_goal, 4).tolist()
    else:
        log.info('goal IK did not converge: only the goal box is kept clear')
    if cfg.d_safe_m > 0:
        cand[crop] &= box_distance(protected, grid.voxel_m, half, cfg.d_safe_m, crop) \
            >= cfg.d_safe_m
    stats['robot_clear'] = int(cand.sum())

    # Clearance from G's position box: voxel centres within half a voxel diagonal of it mark
    # it on the lattice, so the lattice distance may exceed the true one by that much at most.
    T_c = goal.center.to_se3()
    tol = np.asarray(goal.position_tolerance_m)
    slack = grid.voxel_m * math.sqrt(3) / 2
    near_goal = _near_box(sub, T_c, tol, slack)
    if cfg.d_safe_m > 0:
        cand[crop] &= (box_distance(near_goal, grid.voxel_m, half, cfg.d_safe_m, crop)
                       >= cfg.d_safe_m - slack)
    checks.append((coal.Box(*np.maximum(2 * tol, 1e-9)), _tf(T_c), cfg.d_safe_m,
                   'goal region'))
    stats['goal_clear'] = int(cand.sum())
    checks += [(coal_geometry(sh), _tf(sh.pose.to_se3()), _CONTACT_TOL_M,
                f'scene object {o.id}') for o in objects for sh in o.shapes]
    stats['candidates'] = int(cand.sum())
    return SearchRegion(grid, lo, hi, weights, cand, k, s, cfg.d_min_m, checks, stats)


def _shape_bounds(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds of a shape in the base frame (cheap, possibly loose)."""
    T = shape.pose.to_se3()
    if shape.kind == 'box':
        ext = np.abs(T.rotation) @ (np.asarray(shape.dims) / 2)
    elif shape.kind == 'sphere':
        ext = np.full(3, shape.dims[0])
    elif shape.kind == 'cylinder':
        ext = np.full(3, math.hypot(shape.dims[0] / 2, shape.dims[1]))
    else:
        pts = np.asarray(shape.vertices) @ T.rotation.T + T.translation
        return pts.min(axis=0), pts.max(axis=0)
    return T.translation - ext, T.translation + ext


def _occupied(grid: VoxelGrid, shapes: list[Shape]) -> np.ndarray:
    """Voxels whose centre is inside any shape (``voxels.occupied_mask`` with cheap bounds)."""
    mask = np.zeros(grid.shape, dtype=bool)
    for shape in shapes:
        b_lo, b_hi = _shape_bounds(shape)
        i0 = np.clip(grid.index_of(b_lo), 0, grid.shape)
        i1 = np.clip(grid.index_of(b_hi) + 1, 0, grid.shape)
        if np.any(i1 <= i0):
            continue
        if shape.kind == 'mesh':
            sub = occupied_mask(grid, [shape])
            mask |= sub
            continue
        idx = np.stack(np.meshgrid(*[np.arange(i0[a], i1[a]) for a in range(3)],
                                   indexing='ij'), axis=-1)
        mask[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]] |= points_in_shape(shape, grid.centers(idx))
    return mask


def _near_box(grid: VoxelGrid, T_c: pin.SE3, half_m: np.ndarray, within_m: float
              ) -> np.ndarray:
    """Voxel centres within ``within_m`` of the oriented box ``T_c`` of half-extents
    ``half_m``."""
    mask = np.zeros(grid.shape, dtype=bool)
    ext = np.abs(T_c.rotation) @ half_m + within_m
    i0 = np.clip(grid.index_of(T_c.translation - ext), 0, grid.shape)
    i1 = np.clip(grid.index_of(T_c.translation + ext) + 1, 0, grid.shape)
    if np.any(i1 <= i0):
        return mask
    idx = np.stack(np.meshgrid(*[np.arange(i0[a], i1[a]) for a in range(3)],
                               indexing='ij'), axis=-1)
    local = (grid.centers(idx) - T_c.translation) @ T_c.rotation
    mask[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]] = np.linalg.norm(
        np.maximum(np.abs(local) - half_m, 0.0), axis=-1) <= within_m
    return mask


def _tf(T: pin.SE3) -> coal.Transform3s:
    return coal.Transform3s(np.array(T.rotation), np.array(T.translation))


# --------------------------------------------------------------------------------------------
# Methods

Selector = Callable[..., tuple[list, int]]
"""``(region, budget, seed, cfg[, context]) -> ([(window index, mass), ...], rejected picks)``;
``context`` (a :class:`MethodContext`) only for methods registered with ``needs_context``."""


@dataclasses.dataclass(frozen=True)
class MethodContext:
    """The task behind a search region, for planner-in-the-loop methods (PFA, PFA++).

    Ours and Random never get it: they choose from the heatmap and the region alone.
    """

    robot: RobotModel
    objects: tuple[SceneObject, ...]
    q_init: np.ndarray
    goal: GoalRegion
    options: Any = None
    """Method-specific settings from ``attack(method_options=...)`` (e.g. a planner)."""


def _select_greedy(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig):
    return greedy_cover(region.weights, region.candidates, region.k, budget,
                        region.d_min_m / region.grid.voxel_m, region.accept, cfg.max_rejections)


def _select_random(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig):
    return random_cover(region.weights, region.candidates, region.k, budget,
                        region.d_min_m / region.grid.voxel_m, np.random.default_rng(seed),
                        region.accept, cfg.max_rejections)


METHODS: dict[str, Selector] = {'ours': _select_greedy, 'random': _select_random}
"""Attack methods by name. Extension point: planner-in-the-loop baselines (PFA, PFA++) add
themselves with :func:`register_method` when their module is imported."""


PLUGIN_METHODS = {'pfa': 'advocc_ros.attack.pfa', 'pfa++': 'advocc_ros.attack.pfa'}
"""Methods whose module registers them on import (loaded on first use)."""
KNOWN_METHODS = ('ours', 'random', 'pfa', 'pfa++')


CONTEXT_METHODS: set[str] = set()
"""Methods whose selector also takes ``context=MethodContext(...)``."""


def register_method(name: str, selector: Selector, needs_context: bool = False) -> None:
    METHODS[name] = selector
    if needs_context:
        CONTEXT_METHODS.add(name)
    else:
        CONTEXT_METHODS.discard(name)


def load_method(name: str) -> bool:
    """Whether ``name`` is usable, importing its plug-in module if it has one."""
    if name not in METHODS and name in PLUGIN_METHODS:
        try:
            importlib.import_module(PLUGIN_METHODS[name])
        except ModuleNotFoundError as exc:
            log.info('method %s is not available: %s', name, exc)
    return name in METHODS


# --------------------------------------------------------------------------------------------
# Entry point

def validate_request(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...],
                     q_init: np.ndarray, goal: GoalRegion, budget: int, method: str,
                     box_size_m: float, cfg: AttackConfig) -> None:
    """Raise ``AttackError`` with the status and a clear message for a bad request."""
    if not load_method(method):
        raise AttackError(AttackStatus.UNKNOWN_METHOD,
                          f'unknown attack method {method!r}; known: {sorted(METHODS)}')
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) \
            or not 1 <= budget <= cfg.max_budget:
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'budget must be an integer in 1..{cfg.max_budget}, got {budget!r}')
    if not (np.isfinite(box_size_m) and 0 < box_size_m <= cfg.max_box_m):
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'box size must be in (0, {cfg.max_box_m}] m, got {box_size_m!r}')
    expected = heatmap.meta.get('robot_hash')
    if expected is not None and expected != robot.hash:
        raise AttackError(AttackStatus.ROBOT_MISMATCH,
                          f'the heatmap was built for robot {expected}, not {robot.hash}')
    try:
        q_init = robot.check_q(q_init, 'start state')
    except RobotError as exc:
        raise AttackError(AttackStatus.INVALID_START, str(exc)) from None
    if not robot.within_limits(q_init):
        raise AttackError(AttackStatus.INVALID_START,
                          f'start state outside the joint limits: {np.round(q_init, 4).tolist()}')
    if not robot.model.existFrame(goal.link):
        raise AttackError(AttackStatus.INVALID_LINK,
                          f'goal link {goal.link!r} is not a frame of the robot')
    if not any(goal.position_tolerance_m) and not any(goal.orientation_tolerance_rad):
        raise AttackError(AttackStatus.INVALID_GOAL,
                          'goal region is empty: every tolerance is 0 (an unset message?); '
                          'give position half-extents and orientation tolerances')
    world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    if world.in_collision(q_init):
        raise AttackError(AttackStatus.START_IN_COLLISION,
                          'start state is in collision (self or with the scene)')


def attack(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...] | list,
           q_init: np.ndarray, goal: GoalRegion, budget: int, method: str = 'ours',
           cfg: AttackConfig = AttackConfig(), box_size_m: float | None = None,
           seed: int = 0, method_options: Any = None) -> AttackResult:
    """Place at most ``budget`` boxes for one task. Never raises for a bad request: the result
    carries the status and message instead. ``method_options``: settings of a
    planner-in-the-loop method (``advocc_ros.attack.pfa.PfaOptions``)."""
    link_luts(robot, heatmap.grid.voxel_m / 4)  # model loading (~1 s once), not attack time
    t0 = time.perf_counter()
    s = cfg.box_size_m if box_size_m is None or box_size_m == 0 else float(box_size_m)
    base = dict(method=method, budget=int(budget) if isinstance(budget, (int, np.integer))
                else 0, box_size_m=s)
    objects = tuple(objects)
    try:
        validate_request(heatmap, robot, objects, q_init, goal, budget, method, s, cfg)
        q_init = np.asarray(q_init, dtype=float)
        region = search_region(heatmap, robot, objects, q_init, goal, cfg, s)
        extra = {}
        if method in CONTEXT_METHODS:
            extra['context'] = MethodContext(robot, objects, q_init, goal, method_options)
        picks, rejected = METHODS[method](region, int(budget), int(seed), cfg, **extra)
    except AttackError as exc:
        return AttackResult(exc.status, str(exc), compute_s=time.perf_counter() - t0, **base)
    except (SceneError, RobotError) as exc:
        return AttackResult(AttackStatus.INVALID_REQUEST, str(exc),
                            compute_s=time.perf_counter() - t0, **base)
    obstacles = tuple(make_box(f'adv_{i}', np.round(region.center_m(c), 9), (s, s, s))
                      for i, (c, _) in enumerate(picks))
    masses = tuple(float(m) for _, m in picks)
    stats = dict(region.stats, rejected_picks=rejected)
    if len(obstacles) < budget:
        status = AttackStatus.PARTIAL
        message = (f'only {len(obstacles)} of {budget} boxes fit the search region '
                   f'({region.stats.get("candidates", 0)} candidate centres)')
    else:
        status, message = AttackStatus.SUCCESS, f'placed {len(obstacles)} boxes'
    result = AttackResult(status, message, obstacles, masses, float(sum(masses)),
                          time.perf_counter() - t0, stats=stats, **base)
    log.info('attack %s M=%d: %s, mass %.3f, %.1f ms', method, budget, status.value,
             result.total_mass, result.compute_s * 1e3)
    return result


# --------------------------------------------------------------------------------------------
# Obstacles file

def obstacles_data(result: AttackResult, heatmap: Heatmap | None = None,
                   scene_name: str | None = None, scene_hash: str | None = None,
                   extra: dict | None = None) -> dict:
    """The YAML mapping of an obstacles file: ``objects`` (scene-file format) + metadata."""
    data: dict[str, Any] = {
        'format': OBSTACLES_FORMAT, 'version': OBSTACLES_VERSION,
        'status': result.status.value, 'message': result.message,
        'method': result.method, 'budget': result.budget,
        'box_size_m': float(result.box_size_m),
        'masses': [float(m) for m in result.masses], 'total_mass': float(result.total_mass),
        'compute_ms': round(result.compute_s * 1e3, 3),
        'scene': {'name': scene_name, 'objects_hash': scene_hash},
    }
    if heatmap is not None:
        data['heatmap'] = {'robot_hash': heatmap.meta.get('robot_hash'),
                           'scene_hash': heatmap.meta.get('scene_hash'),
                           'robot_only': heatmap.robot_only,
                           'valid_samples': heatmap.meta.get('valid_samples'),
                           'seeds': heatmap.meta.get('seeds'), **heatmap.grid.to_data()}
    data.update(extra or {})
    data['objects'] = objects_to_data(result.obstacles)
    return data


def save_obstacles(path: str | pathlib.Path, data: dict) -> None:
    """Write an obstacles file atomically (see :func:`obstacles_data`)."""
    save_yaml_atomic(path, data)


def load_obstacles(path: str | pathlib.Path) -> tuple[tuple[SceneObject, ...], dict]:
    """(objects, metadata) of an obstacles file; errors name the file and field."""
    path = pathlib.Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict) or 'objects' not in data:
        raise SceneError(f'{path}: expected a mapping with objects: [...]')
    objects = objects_from_data(data['objects'], f'{path}.objects', path.parent)
    meta = {k: v for k, v in data.items() if k != 'objects'}
    return objects, meta


__all__ = ['AttackConfig', 'AttackError', 'AttackResult', 'AttackStatus', 'CONTEXT_METHODS',
           'KNOWN_METHODS', 'METHODS', 'MethodContext', 'SearchRegion', 'attack', 'box_distance',
           'box_sum', 'goal_configuration', 'greedy_cover', 'load_method', 'load_obstacles',
           'obstacles_data', 'random_cover', 'register_method', 'save_obstacles',
           'search_region', 'validate_request']
