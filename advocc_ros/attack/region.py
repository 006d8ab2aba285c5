"""Step 2 of the attack: the search region, constraints C1-C3 on the heatmap grid, with its
exact box checks (docs/design.md)."""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any, Protocol

import coal
import numpy as np
import pinocchio as pin

from advocc_ros import kernels
from advocc_ros.attack.coverage import box_distance, box_half_voxels
from advocc_ros.attack.types import AttackConfig
from advocc_ros.heatmap import Heatmap, link_tables
from advocc_ros.heatmap.config import HeatmapConfig, weight_config
from advocc_ros.model.collision import coal_geometry, shared_world
from advocc_ros.kinematics.ik import goal_configuration
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject
from advocc_ros.model.voxels import VoxelGrid

log = logging.getLogger(__name__)

_CONTACT_TOL_M = 1e-6


# --------------------------------------------------------------------------------------------
# The task-level search region

def robot_occupancy(robot: RobotModel, placements: list[pin.SE3], grid: VoxelGrid,
                    lo: np.ndarray, hi: np.ndarray, lut_pitch_m: float,
                    links: list[int] | None = None) -> np.ndarray:
    """bool mask of the window ``[lo, hi)`` of ``grid``: voxel centres inside the robot's
    link solids at ``placements`` (``T_base_geom`` per collision geometry), rasterized with
    the heatmap's link tables (``Heatmap.lut_pitch_m``)."""
    R = np.array([T.rotation for T in placements])
    t = np.array([T.translation for T in placements])
    origin = np.asarray(grid.origin_m) + np.asarray(lo) * grid.voxel_m
    return link_tables(robot, lut_pitch_m).rasterize(
        np.zeros(tuple(hi - lo), dtype=bool), origin, grid.voxel_m, R, t, links)


class Guard(Protocol):
    """A goal policy's check of each pick (``attack.policy``: ``GoalGuard`` under
    ``reachable``, ``WitnessGuard`` under ``solvable``)."""

    reason: str
    """Why a refused box is refused (the rejection's log line)."""

    def admit(self, center_m: np.ndarray) -> bool:
        """Whether the box at ``center_m`` may be placed (a guard may count it as placed)."""


@dataclasses.dataclass(frozen=True)
class SearchRegion:
    """Candidates and masses over a window ``[lo, hi)`` of the heatmap grid, plus the exact
    checker for boxes. Build it with :func:`search_region` (step 2 of the attack); a later step
    that narrows it returns a new one (``dataclasses.replace``)."""

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
    """The counts of each filter (``corridor``, ``box_fits``, ..., ``candidates``)."""
    lut_pitch_m: float
    """Pitch of the heatmap's link look-up tables [m]: rasterize the robot as the build did."""
    guard: Guard | None = None
    """The goal policy's guard, None under ``paper``: the policy step (``attack.policy``)
    returns a new region with it (and the candidates it drops)."""
    weight_config: HeatmapConfig = HeatmapConfig()
    """w(q)'s parameters, the heatmap's own (methods that weigh configurations use them)."""

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
        """Whether the box at window index ``c`` passes the exact checks (and the goal guard,
        which then counts it as placed)."""
        center = self.center_m(c)
        what = self.box_violation(center)
        if what is None and self.guard is not None and not self.guard.admit(center):
            what = self.guard.reason
        if what is not None:
            log.debug('candidate %s rejected by the exact check: %s', c.tolist(), what)
        return what is None


@dataclasses.dataclass(frozen=True)
class _Window:
    """The part of the heatmap grid one task's region looks at: ``[lo, hi)``, the corridor's
    bounding box padded for the box and distance tests; ``crop`` is the corridor's part of it
    (window indices)."""

    lo: np.ndarray
    hi: np.ndarray
    crop_lo: np.ndarray
    crop_hi: np.ndarray
    grid: VoxelGrid | None
    """The window as a grid of its own (None: the window is empty)."""

    @property
    def slices(self) -> tuple[slice, slice, slice]:
        return tuple(slice(self.lo[a], self.hi[a]) for a in range(3))

    @property
    def crop(self) -> tuple[slice, slice, slice]:
        return tuple(slice(self.crop_lo[a], self.crop_hi[a]) for a in range(3))


def _window(grid: VoxelGrid, x_start: np.ndarray, x_goal: np.ndarray, cfg: AttackConfig,
            half: float, k: int) -> _Window:
    """The window of the corridor from ``x_start`` to ``x_goal`` (``grid`` None: empty)."""
    reach = max(cfg.d_safe_m, _CONTACT_TOL_M) + half
    pad = int(math.ceil(reach / grid.voxel_m)) + k + 1
    c_lo = grid.index_of(np.minimum(x_start, x_goal) - cfg.corridor_radius_m)
    c_hi = grid.index_of(np.maximum(x_start, x_goal) + cfg.corridor_radius_m) + 1
    shape = np.asarray(grid.shape)
    lo = np.clip(c_lo - pad, 0, shape)
    hi = np.clip(c_hi + pad, 0, shape)
    if np.any(hi <= lo):
        return _Window(lo, lo, lo, lo, None)
    sub = VoxelGrid(tuple(grid.centers(lo) - grid.voxel_m / 2), grid.voxel_m, tuple(hi - lo))
    return _Window(lo, hi, np.maximum(c_lo - lo, 0), np.maximum(c_hi - lo, 0), sub)


def search_region(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...],
                  q_init: np.ndarray, goal: GoalRegion, cfg: AttackConfig = AttackConfig(),
                  box_size_m: float | None = None) -> SearchRegion:
    """Candidate centres X (Algorithm 1, lines 1-2) for one task: C1 (corridor), C2 (the box
    fits), C3 (clearance from the robot at ``q_init`` and from G: a ``joint`` goal's body);
    see docs/design.md and docs/goal_forms.md."""
    grid = heatmap.grid
    s = cfg.box_size_m if box_size_m is None else float(box_size_m)
    k = box_half_voxels(s, grid.voxel_m)
    x_start = np.array(robot.ee_pose(q_init, link=goal.link,
                                     tool=goal.tool_offset.to_se3()).translation)
    x_goal = np.array(goal.center.position_m)
    stats: dict[str, Any] = {'x_start_m': x_start.round(4).tolist(),
                             'x_goal_m': x_goal.round(4).tolist(), 'k_voxels': k}
    window = _window(grid, x_start, x_goal, cfg, s / 2, k)
    if window.grid is None:
        empty = np.zeros((0, 0, 0))
        stats['candidates'] = 0
        return SearchRegion(grid, window.lo, window.lo, empty, empty.astype(bool), k, s,
                            cfg.d_min_m, [], stats, heatmap.lut_pitch_m,
                            weight_config=weight_config(heatmap))
    weights, cand, free = _corridor(heatmap, robot, objects, window, x_start, x_goal, cfg,
                                    stats)
    # C2, the box fits: no non-free voxel centre inside it (U(c) in V_free).
    cand[window.crop] &= box_distance(~free, grid.voxel_m, s / 2, _CONTACT_TOL_M,
                                      window.crop) > 0
    stats['box_fits'] = int(cand.sum())
    checks = _robot_clearance(heatmap, robot, q_init, goal, cfg, window, cand, s / 2, stats)
    checks += (_joint_goal_clearance(heatmap, robot, goal, cfg, window, cand, s / 2, stats)
               if goal.is_joint else _goal_clearance(grid, goal, cfg, window, cand, s / 2, stats))
    checks += [(coal_geometry(sh), _tf(sh.pose.to_se3()), _CONTACT_TOL_M,
                f'scene object {o.id}') for o in objects for sh in o.shapes]
    stats['candidates'] = int(cand.sum())
    return SearchRegion(grid, window.lo, window.hi, weights, cand, k, s, cfg.d_min_m, checks,
                        stats, heatmap.lut_pitch_m, weight_config=weight_config(heatmap))


def _corridor(heatmap: Heatmap, robot: RobotModel, objects, window: _Window,
              x_start: np.ndarray, x_goal: np.ndarray, cfg: AttackConfig, stats: dict):
    """C1: (window weights: H on the current V_free, candidate mask, V_free) with the corridor
    candidates: H > 0, in V_free (of the file and not inside the current scene), within
    ``r_corr`` of the segment; their counts in ``stats``."""
    grid = heatmap.grid
    shapes = [sh for o in objects for sh in o.shapes]
    win = window.slices
    free = heatmap.free[win] & ~shared_world(robot, shapes).occupied(grid)[win]
    weights = np.where(free, heatmap.values[win], 0.0)
    # voxels with H > 0 within r_corr of the segment; how many had H > 0
    cand, stats['free_positive'] = kernels.corridor_candidates(
        weights, window.crop_lo, np.minimum(window.crop_hi, window.hi - window.lo),
        np.asarray(window.grid.origin_m), grid.voxel_m, x_start, x_goal, cfg.corridor_radius_m)
    stats['corridor'] = int(cand.sum())
    return weights, cand, free


def _robot_clearance(heatmap: Heatmap, robot: RobotModel, q_init: np.ndarray, goal: GoalRegion,
                     cfg: AttackConfig, window: _Window, cand: np.ndarray, half: float,
                     stats: dict) -> list:
    """C3 for the robot: drop the candidates within ``d_safe`` of the robot at ``q_init`` (and
    of the hand at one goal configuration with ``protect_goal_hand``); the exact checks."""
    grid, lo, hi = heatmap.grid, window.lo, window.hi
    world = shared_world(robot)
    links = world.geom_model.geometryObjects[:world.n_links]
    placements = [pin.SE3(T) for T in world.link_placements(q_init)]
    protected = robot_occupancy(robot, placements, grid, lo, hi, heatmap.lut_pitch_m)
    checks = [(g.geometry, _tf(T), cfg.d_safe_m, f'robot link {g.name} at q_init')
              for g, T in zip(links, placements)]
    q_goal = goal_configuration(robot, goal, q_init) if cfg.protect_goal_hand else None
    stats['goal_ik'] = None if not cfg.protect_goal_hand else q_goal is not None
    if q_goal is not None:
        joint = robot.model.frames[robot.model.getFrameId(goal.link)].parentJoint
        hand = [i for i, g in enumerate(links) if g.parentJoint == joint]
        goal_placements = [pin.SE3(T) for T in world.link_placements(q_goal)]
        protected |= robot_occupancy(robot, goal_placements, grid, lo, hi,
                                     heatmap.lut_pitch_m, hand)
        checks += [(links[i].geometry, _tf(goal_placements[i]), cfg.d_safe_m,
                    f'hand {links[i].name} at goal') for i in hand]
        stats['q_goal'] = np.round(q_goal, 4).tolist()
    elif cfg.protect_goal_hand:
        log.info('goal IK did not converge: only the goal box is kept clear')
    if cfg.d_safe_m > 0:
        cand[window.crop] &= box_distance(protected, grid.voxel_m, half, cfg.d_safe_m,
                                          window.crop) >= cfg.d_safe_m
    stats['robot_clear'] = int(cand.sum())
    return checks


def _joint_goal_clearance(heatmap: Heatmap, robot: RobotModel, goal: GoalRegion,
                          cfg: AttackConfig, window: _Window, cand: np.ndarray, half: float,
                          stats: dict) -> list:
    """C3 for a ``joint`` goal: the goal is that configuration, so its whole body keeps the
    witness guard's clearance (the certificate's guard margin plus ``victim_margin_m``) from
    every box, as the witness's does, under every policy; the goal region's d_safe does not
    apply, and boxes may close in around the hand. The exact checks."""
    from advocc_ros.planning.certificate import CertificateConfig

    clearance_m = CertificateConfig().guard_margin_m + cfg.victim_margin_m
    world = shared_world(robot)
    links = world.geom_model.geometryObjects[:world.n_links]
    q_goal = goal.configuration(robot.joint_names)
    placements = [pin.SE3(T) for T in world.link_placements(q_goal)]
    body = robot_occupancy(robot, placements, heatmap.grid, window.lo, window.hi,
                           heatmap.lut_pitch_m)
    cand[window.crop] &= box_distance(body, heatmap.grid.voxel_m, half, clearance_m,
                                      window.crop) >= clearance_m
    stats['goal_clear'] = int(cand.sum())
    return [(g.geometry, _tf(T), clearance_m, f'robot link {g.name} at the joint goal')
            for g, T in zip(links, placements)]


def _goal_clearance(grid: VoxelGrid, goal: GoalRegion, cfg: AttackConfig, window: _Window,
                    cand: np.ndarray, half: float, stats: dict) -> list:
    """C3 for G's position box: voxel centres within half a voxel diagonal of it mark it on the
    lattice, so the lattice distance may exceed the true one by that much at most; the exact
    check."""
    T_c = goal.center.to_se3()
    tol = np.asarray(goal.position_tolerance_m)
    slack = grid.voxel_m * math.sqrt(3) / 2
    near_goal = _near_box(window.grid, T_c, tol, slack)
    if cfg.d_safe_m > 0:
        cand[window.crop] &= (box_distance(near_goal, grid.voxel_m, half, cfg.d_safe_m,
                                           window.crop) >= cfg.d_safe_m - slack)
    stats['goal_clear'] = int(cand.sum())
    return [(coal.Box(*np.maximum(2 * tol, 1e-9)), _tf(T_c), cfg.d_safe_m, 'goal region')]


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
