"""Coverage selection on voxel arrays: box sums, box distances, greedy and random covers.

Greedy: box sums of the uncovered mass by separable shift-adds over a window around the
corridor; after each pick only the sums within 2k voxels of it change and are recomputed
locally. Random baseline: candidates in a seeded random order under the same constraints.
Numpy, and compiled kernels (``advocc_ros.kernels``) for the line sums and box distances;
tested against brute force.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Callable

import numpy as np

from advocc_ros import kernels
from advocc_ros.attack.types import AttackConfig

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Grid helpers (all vectorized; no Python loop over voxels)

def box_half_voxels(box_size_m: float, voxel_m: float) -> int:
    """k such that U(c) is the (2k+1)^3 cube of voxels whose centres lie in the box."""
    return int(math.floor(box_size_m / 2 / voxel_m + 1e-9))


def box_sum(values: np.ndarray, k: int) -> np.ndarray:
    """Sum of ``values`` over the (2k+1)^3 cube around each voxel (zero outside the array).

    Separable line sums, not an integral volume: no cancellation, and each sum adds the same
    terms in the same order wherever it is computed, so a sub-block gives bit-identical sums
    to the full array and local updates match a full recomputation.
    """
    out = np.asarray(values, dtype=np.float64)
    for axis in range(3):
        out = np.moveaxis(kernels.line_sums(np.moveaxis(out, axis, -1), k), -1, axis)
    return np.ascontiguousarray(out)


def _padded_bounds(mask: np.ndarray, pad: int) -> tuple[slice, slice, slice] | None:
    """The bounding box of ``mask``'s True voxels grown by ``pad`` (clipped); None if none."""
    block = []
    for a in range(3):
        hit = np.flatnonzero(mask.any(axis=tuple(b for b in range(3) if b != a)))
        if not len(hit):
            return None
        block.append(slice(max(int(hit[0]) - pad, 0), min(int(hit[-1]) + pad + 1, mask.shape[a])))
    return tuple(block)


def box_distance(mask: np.ndarray, voxel_m: float, half_m: float, max_m: float,
                 crop: tuple[slice, slice, slice] | None = None) -> np.ndarray:
    """Distance [m] from the closed box (half-edge ``half_m``) centred on each voxel centre to
    the nearest True voxel centre of ``mask``; ``inf`` beyond ``max_m``. ``crop``: only this
    part of the output is wanted (the input around it still counts).

    Exact on the lattice (float32): the squared distance is a sum of per-axis costs
    ``max(|dx| - half, 0)^2``, so three 1-D min-convolutions (generalized distance transform)
    give it, each over the few offsets that can stay within ``max_m``; each pass computes only
    the rows of its axis inside ``crop`` and near the mask, in a compiled kernel.
    """
    reach = int(math.ceil((max_m + half_m) / voxel_m))
    costs = [0.0]
    for o in range(1, reach + 1):
        cost = max(o * voxel_m - half_m, 0.0) ** 2
        if cost > max_m ** 2:
            break
        costs.append(cost)
    costs = np.array(costs, dtype=np.float32)
    rows = [(crop[a] if crop is not None else slice(None)).indices(mask.shape[a])[:2]
            for a in range(3)]
    rows = [(start, max(stop, start)) for start, stop in rows]
    result = np.full([stop - start for start, stop in rows], np.inf)
    # Only voxels within ``len(costs) - 1`` rows of the mask's bounding box can be finite:
    # transform that block alone (the masks are mostly small: the robot, the goal box).
    block = _padded_bounds(mask, len(costs) - 1)
    if block is None:
        return result
    out_rows, dst = [], []
    for a, b in enumerate(block):
        start, stop = max(rows[a][0], b.start), min(rows[a][1], b.stop)
        if stop <= start:
            return result
        out_rows.append((start - b.start, stop - b.start))
        dst.append(slice(start - rows[a][0], stop - rows[a][0]))
    out = np.where(mask[block], np.float32(0), np.float32(np.inf))
    for axis in range(3):
        line = kernels.min_plus(np.moveaxis(out, axis, -1), costs, *out_rows[axis])
        out = np.moveaxis(line, -1, axis)
    result[tuple(dst)] = np.sqrt(out, dtype=np.float64)
    return result


def _ball_offsets(radius_vox: float) -> np.ndarray:
    """Integer offsets (n, 3) strictly closer than ``radius_vox`` to the origin."""
    r = int(math.ceil(radius_vox))
    g = np.arange(-r, r + 1)
    off = np.stack(np.meshgrid(g, g, g, indexing='ij'), -1).reshape(-1, 3)
    return off[np.einsum('ij,ij->i', off, off) < radius_vox ** 2 - 1e-9]


# --------------------------------------------------------------------------------------------
# Coverage selection on arrays (shared by every method; tested against brute force)

@dataclasses.dataclass
class Coverage:
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
        self._drop = _ball_offsets(self.d_min_vox) if self.d_min_vox > 0 \
            else np.zeros((1, 3), int)

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
                 d_min_vox: float, accept: Accept | None = None,
                 max_rejections: int = AttackConfig.max_rejections
                 ) -> tuple[list[tuple[np.ndarray, float]], int]:
    """Algorithm 1 on arrays: up to ``budget`` (index, marginal mass) picks, and rejections.

    ``U(c)`` is the (2k+1)^3 cube around index c; picks are >= ``d_min_vox`` voxels apart.
    Ties go to the first index in C order, so the result is deterministic.
    """
    if not np.any(candidates):
        return [], 0
    # The candidates' bounding box padded by 3k: every sum a pick reads or updates (within 2k
    # of a candidate) depends only on mass inside it, so selection on this block gives the same
    # picks and masses as on the whole window, with less to sum and to search.
    block = _padded_bounds(candidates, 3 * k)
    shift = np.array([b.start for b in block])
    cov = Coverage(weights[block], candidates[block], k, d_min_vox)
    picks, rejected = [], 0
    score = np.where(cov.candidates, cov.sums, -np.inf)
    while len(picks) < budget:
        flat = int(np.argmax(score))
        if score.flat[flat] == -np.inf:
            break
        c = np.array(np.unravel_index(flat, score.shape))
        if accept is not None and not accept(c + shift):
            cov.candidates[tuple(c)] = False
            score.flat[flat] = -np.inf
            rejected += 1
            if rejected > max_rejections:
                log.warning('greedy: %d picks failed the exact check; giving up', rejected)
                break
            continue
        picks.append((c + shift, cov.cover(c)))
        region = cov._block(c, max(2 * k, int(math.ceil(d_min_vox))))
        score[region] = np.where(cov.candidates[region], cov.sums[region], -np.inf)
    return picks, rejected


def random_cover(weights: np.ndarray, candidates: np.ndarray, k: int, budget: int,
                 d_min_vox: float, rng: np.random.Generator, accept: Accept | None = None,
                 max_rejections: int = AttackConfig.max_rejections
                 ) -> tuple[list[tuple[np.ndarray, float]], int]:
    """Random baseline: candidates uniformly at random (without replacement) under the same
    constraints as :func:`greedy_cover`; masses are the marginal coverage, as for greedy."""
    cov = Coverage(weights, candidates, k, d_min_vox)
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
