"""Compiled kernels of the heatmap, the attack and the batched kinematics, in C (sources
beside this file; ``loader`` builds and loads them).

Each function here checks its arrays (dtype, C order, shapes the C side relies on) and calls
one C function; the parallel ones run on ``limits.worker_threads()`` threads, rows split
between them (rows are independent, so the result does not depend on the count). What each
computes is said where it is used: ``kinematics.batch``, ``heatmap.build`` and the attack's
``coverage``, ``configurations`` and ``region``."""

from __future__ import annotations

import ctypes

import numpy as np

from advocc_ros.kernels.loader import KernelBuildError, library
from advocc_ros.limits import worker_threads

_P, _I, _D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
_SIGNATURES = {
    'advocc_frames': (None, [_I, _I, _I] + [_P] * 7 + [_I]),
    'advocc_link_frames': (None, [_I] * 3 + [_P] * 6 + [_I] + [_P] * 4),
    'advocc_contains': (None, [_I] + [_P] * 6 + [_I]),
    'advocc_dls': (None, [_I, _I, _I] + [_P] * 4 + [_D, _D] + [_P] * 11 + [_I]),
    'advocc_accumulate': (None, [_P] * 4 + [_D, _P, _I, _I] + [_P] * 3 + [_I] + [_P] * 4
                          + [_D, _P, _P]),
    'advocc_cover': (None, [_P, _I, _I, _P, _P, _I, _I, _I, _P, _P, _P, _I, _P, _D, _I, _I]
                     + [_P] * 6 + [_D, _P, _P, _I]),
    'advocc_line_sums': (None, [_P, _I, _I, _I, _P]),
    'advocc_min_plus': (None, [_P, _I, _I, _P, _I, _I, _I, _P]),
    'advocc_corridor_candidates': (_I, [_P] * 5 + [_D, _P, _P, _D, _P]),
    'advocc_csr_indptr': (_I, [_P, _I, _I, _P, _I]),
    'advocc_csr_indices': (None, [_P, _I, _I, _P, _P, _I]),
}
_FUNCTIONS: dict = {}
MAX_JOINTS = 64
"""Joints of a chain and entries of its configuration the kinematics kernels take (their
scratch is on the stack); ``kinematics.batch`` uses pinocchio beyond."""


def _call(name: str, *args):
    """``name`` of the library with ``args`` (its ctypes signature set on first use)."""
    fn = _FUNCTIONS.get(name)
    if fn is None:
        fn = getattr(library(), name)
        fn.restype, fn.argtypes = _SIGNATURES[name]
        _FUNCTIONS[name] = fn
    return fn(*args)


def _in(a, dtype, shape: tuple | None = None) -> np.ndarray:
    """``a`` as a C-ordered array of ``dtype`` (a copy only if needed); ``ValueError`` when
    its shape is not ``shape`` (None: any)."""
    a = np.ascontiguousarray(a, dtype=dtype)
    if shape is not None and a.shape != shape:
        raise ValueError(f'kernel argument of shape {a.shape}, expected {shape}')
    return a


def _out(a: np.ndarray, dtype, shape: tuple) -> np.ndarray:
    """An array the kernel writes into: it must be ``dtype``, C-ordered, writeable and of
    ``shape`` already (``ValueError`` otherwise: a copy would lose the writes)."""
    if (not isinstance(a, np.ndarray) or a.dtype != dtype or not a.flags.c_contiguous
            or not a.flags.writeable or a.shape != shape):
        raise ValueError(f'kernel output {getattr(a, "dtype", type(a))} {np.shape(a)}: '
                         f'expected a writeable C-ordered {np.dtype(dtype)} array {shape}')
    return a


def _ptr(a: np.ndarray) -> int:
    return a.ctypes.data


class Chain:
    """A kinematic chain's arrays as the C kernels read them (``kinematics.batch``)."""

    def __init__(self, T_parent_joint, axis, revolute, index_q, T_joint_frame, nq: int):
        self.nj = len(revolute)
        self.nq = int(nq)
        if self.nj > MAX_JOINTS or (self.nj and self.nq > MAX_JOINTS):
            raise ValueError(f'a chain of {self.nj} joints and {self.nq} values: the kernels '
                             f'take at most {MAX_JOINTS}')
        self.T_pj = _in(T_parent_joint, np.float64, (self.nj, 4, 4))
        self.axis = _in(axis, np.float64, (self.nj, 3))
        self.revolute = _in(revolute, np.bool_, (self.nj,))
        self.index_q = _in(index_q, np.int64, (self.nj,))
        if self.nj and not (0 <= self.index_q.min() and self.index_q.max() < self.nq):
            raise ValueError('joint index outside the configuration')
        self.T_jf = _in(T_joint_frame, np.float64, (4, 4))

    def args(self) -> tuple:
        return (_ptr(self.T_pj), _ptr(self.axis), _ptr(self.revolute), _ptr(self.index_q),
                _ptr(self.T_jf))


def frames(chain: Chain, Q: np.ndarray, out: np.ndarray) -> None:
    """``out[i]`` = T_base_frame at ``Q[i]``."""
    Q = _in(Q, np.float64, (len(Q), chain.nq))
    _out(out, np.float64, (len(Q), 4, 4))
    _call('advocc_frames', len(Q), chain.nj, chain.nq, _ptr(Q), *chain.args(), _ptr(out),
          worker_threads())


def link_frames(chain: Chain, parent: np.ndarray, Q: np.ndarray, column: np.ndarray,
                placements: np.ndarray) -> np.ndarray:
    """(N, L, 4, 4): ``T_base_joint[column[l]] @ placements[l]`` at each ``Q[i]``, the joint
    frames each after its parent (``parent[j] = -1``: the base, column ``nj``); one thread."""
    Q = _in(Q, np.float64, (len(Q), chain.nq))
    parent = _in(parent, np.int64, (chain.nj,))
    if np.any((parent >= np.arange(chain.nj)) | (parent < -1)):
        raise ValueError('a joint before its parent')
    column = _in(column, np.int64)
    if column.ndim != 1 or np.any((column < 0) | (column > chain.nj)):
        raise ValueError('a link on no joint of the chain')
    placements = _in(placements, np.float64, (len(column), 4, 4))
    out = np.empty((len(Q), len(column), 4, 4))
    scratch = np.empty((chain.nj + 1, 4, 4))
    _call('advocc_link_frames', len(Q), chain.nj, chain.nq, _ptr(Q), _ptr(parent),
          _ptr(chain.T_pj), _ptr(chain.axis), _ptr(chain.revolute), _ptr(chain.index_q),
          len(column), _ptr(column), _ptr(placements), _ptr(scratch), _ptr(out))
    return out


def _box_args(T_center, T_link_tool, pos_tol, rot_tol) -> list[np.ndarray]:
    return [_in(T_center, np.float64, (4, 4)), _in(T_link_tool, np.float64, (4, 4)),
            _in(pos_tol, np.float64, (3,)), _in(rot_tol, np.float64, (3,))]


def contains(T_links: np.ndarray, T_center, T_link_tool, pos_tol, rot_tol) -> np.ndarray:
    """(N,) whether each link pose (N, 4, 4) puts the tool in the pose box."""
    T_links = _in(T_links, np.float64)
    T_links = T_links.reshape(-1, 4, 4)
    out = np.zeros(len(T_links), dtype=np.bool_)
    box = _box_args(T_center, T_link_tool, pos_tol, rot_tol)
    _call('advocc_contains', len(T_links), _ptr(T_links), *map(_ptr, box), _ptr(out),
          worker_threads())
    return out


def dls(chain: Chain, Q: np.ndarray, done: np.ndarray, T_target, iterations, damping: float,
        max_step: float, lower, upper, T_center, T_link_tool, pos_tol, rot_tol) -> None:
    """Damped least squares in place on ``Q`` (n, nq), row i at most ``iterations[i]`` steps
    towards ``T_target[i]``, stopping (``done[i]``) once its frame is in the pose box."""
    n, nq = len(Q), chain.nq
    _out(Q, np.float64, (n, nq))
    _out(done, np.bool_, (n,))
    T_target = _in(T_target, np.float64, (n, 4, 4))
    iterations = _in(iterations, np.int64, (n,))
    lower, upper = _in(lower, np.float64, (nq,)), _in(upper, np.float64, (nq,))
    box = _box_args(T_center, T_link_tool, pos_tol, rot_tol)
    _call('advocc_dls', n, chain.nj, nq, _ptr(Q), _ptr(done), _ptr(T_target),
          _ptr(iterations), float(damping), float(max_step), _ptr(lower), _ptr(upper),
          *chain.args(), *map(_ptr, box), worker_threads())


class Tables:
    """Packed link look-up tables (``heatmap.build.LinkTables``) as the kernels read them."""

    def __init__(self, data, offset, shape, origin, pitch: float, box_lo, box_hi,
                 links=None):
        n = len(shape)
        links = np.arange(n) if links is None else np.asarray(links, np.int64)
        self.data = _in(data, np.uint8)
        self.shape = _in(np.asarray(shape)[links], np.int64, (len(links), 3))
        self.offset = _in(np.asarray(offset)[links], np.int64, (len(links),))
        ends = self.offset + self.shape.prod(axis=1)
        if np.any(self.shape <= 0) or np.any(self.offset < 0) or np.any(ends > len(self.data)):
            raise ValueError('link tables outside their data')
        self.origin = _in(np.asarray(origin)[links], np.float64, (len(links), 3))
        self.box_lo = _in(np.asarray(box_lo)[links], np.float64, (len(links), 3))
        self.box_hi = _in(np.asarray(box_hi)[links], np.float64, (len(links), 3))
        self.pitch = float(pitch)
        self.n_links = len(links)


def _placements(tables: Tables, R, t) -> tuple[np.ndarray, np.ndarray]:
    R = _in(R, np.float64)
    n = R.shape[0] if R.ndim == 4 else -1
    R = _in(R, np.float64, (n, tables.n_links, 3, 3))
    return R, _in(t, np.float64, (n, tables.n_links, 3))


def accumulate(H: np.ndarray, stamp: np.ndarray, free: np.ndarray, origin_m, voxel_m: float,
               grid_shape, R, t, weights, sample0: int, tables: Tables) -> None:
    """``H[v] += weights[s]`` for every free voxel v whose centre is inside a link at sample
    s (R (n, L, 3, 3), t (n, L, 3)), once per sample (``stamp``: the last sample that added
    to a voxel; samples numbered from ``sample0``). H, stamp and free are flat grids."""
    grid_shape = _in(grid_shape, np.int64, (3,))
    size = int(np.prod(grid_shape))
    _out(H, np.float64, (size,))
    _out(stamp, np.int64, (size,))
    free = _in(free, np.bool_, (size,))
    R, t = _placements(tables, R, t)
    weights = _in(weights, np.float64, (len(R),))
    origin_m = _in(origin_m, np.float64, (3,))
    _call('advocc_accumulate', _ptr(H), _ptr(stamp), _ptr(free), _ptr(origin_m),
          float(voxel_m), _ptr(grid_shape), len(R), tables.n_links, _ptr(R), _ptr(t),
          _ptr(weights), int(sample0), _ptr(tables.data), _ptr(tables.offset),
          _ptr(tables.shape), _ptr(tables.origin), tables.pitch, _ptr(tables.box_lo),
          _ptr(tables.box_hi))


def cover(cover: np.ndarray, starts: np.ndarray, cand_id: np.ndarray, near: np.ndarray,
          near_z: np.ndarray, stamp: np.ndarray, union: bool, origin_m, voxel_m: float,
          k: int, R, t, tables: Tables) -> None:
    """``cover[r, cand_id[c]] = True`` for every candidate c whose cube (half-width k voxels)
    holds a voxel centre inside a link at a configuration of row r (``starts[r]`` to
    ``starts[r + 1]``); ``near``, ``near_z`` and ``stamp`` padded by k; with ``union`` only
    ``stamp`` is written (``attack.configurations``' ``_Lattice.scan`` says more)."""
    k = int(k)
    cand_id = _in(cand_id, np.int64)
    if cand_id.ndim != 3 or k < 0:
        raise ValueError('candidate ids must be a 3-D grid and k >= 0')
    nx, ny, nz = cand_id.shape
    padded = (nx + 2 * k, ny + 2 * k, nz + 2 * k)
    near = _in(near, np.bool_, padded)
    near_z = _in(near_z, np.int64, padded[:2] + (2,))
    _out(stamp, np.int64, padded)
    R, t = _placements(tables, R, t)
    starts = _in(starts, np.int64)
    rows = len(starts) - 1
    if rows < 0 or np.any(np.diff(starts) < 0) or starts[0] < 0 or starts[-1] > len(R):
        raise ValueError('row starts must rise within the configurations')
    n_cand = int(cand_id.max(initial=-1)) + 1
    if union:
        cover_ptr = None
    else:
        if cover.ndim != 2 or cover.shape[0] != rows or cover.shape[1] < n_cand:
            raise ValueError(f'cover matrix {cover.shape} for {rows} rows, {n_cand} candidates')
        _out(cover, np.bool_, cover.shape)
        cover_ptr = _ptr(cover)
    origin_m = _in(origin_m, np.float64, (3,))
    _call('advocc_cover', cover_ptr, cover.shape[1] if cover.ndim == 2 else 0, rows,
          _ptr(starts), _ptr(cand_id), nx, ny, nz, _ptr(near), _ptr(near_z), _ptr(stamp),
          int(bool(union)), _ptr(origin_m), float(voxel_m), k, tables.n_links, _ptr(R),
          _ptr(t), _ptr(tables.data), _ptr(tables.offset), _ptr(tables.shape),
          _ptr(tables.origin), tables.pitch, _ptr(tables.box_lo), _ptr(tables.box_hi),
          worker_threads())


def line_sums(src: np.ndarray, k: int) -> np.ndarray:
    """``out[..., i]`` = the sum of ``src[..., i - k : i + k + 1]`` along the last axis (terms
    outside skipped), each added in the same order: i, i - 1, i + 1, ..."""
    src = _in(src, np.float64)
    out = np.empty_like(src)
    n = src.shape[-1] if src.ndim else 1
    if src.size:
        _call('advocc_line_sums', _ptr(src), src.size // n, n, int(k), _ptr(out))
    return out


def min_plus(src: np.ndarray, costs: np.ndarray, start: int, stop: int) -> np.ndarray:
    """``out[..., i - start] = min_o src[..., i + o] + costs[|o|]`` along the last axis for i in
    [start, stop), offsets inside the line (``costs`` must not decrease; float32)."""
    src = _in(src, np.float32)
    costs = _in(costs, np.float32)
    if src.ndim < 1 or costs.ndim != 1 or not 0 <= start <= stop <= src.shape[-1]:
        raise ValueError('min_plus: a line range outside the array')
    out = np.empty(src.shape[:-1] + (stop - start,), dtype=np.float32)
    n = src.shape[-1]
    lines = src.size // n if n else 0
    if lines:  # the kernel fills the output (inf where no voxel is within reach)
        _call('advocc_min_plus', _ptr(src), lines, n, _ptr(costs), len(costs), int(start),
              int(stop), _ptr(out))
    return out


def corridor_candidates(weights: np.ndarray, lo, hi, origin_m, voxel_m: float, a_m, b_m,
                        radius_m: float) -> tuple[np.ndarray, int]:
    """Voxels of ``weights[lo:hi]`` with positive mass whose centre lies within ``radius_m``
    of the segment a-b, and how many had positive mass."""
    weights = _in(weights, np.float64)
    if weights.ndim != 3:
        raise ValueError('corridor weights must be a 3-D grid')
    shape = np.array(weights.shape, np.int64)
    lo = np.clip(_in(lo, np.int64, (3,)), 0, shape)
    hi = np.clip(_in(hi, np.int64, (3,)), 0, shape)
    cand = np.zeros(weights.shape, dtype=np.bool_)
    positive = _call('advocc_corridor_candidates', _ptr(weights), _ptr(shape), _ptr(lo),
                     _ptr(hi), _ptr(_in(origin_m, np.float64, (3,))), float(voxel_m),
                     _ptr(_in(a_m, np.float64, (3,))), _ptr(_in(b_m, np.float64, (3,))),
                     float(radius_m), _ptr(cand))
    return cand, int(positive)


def dense_to_csr(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR ``indptr`` and (sorted) ``indices`` of a 2-D bool matrix."""
    dense = _in(dense, np.bool_)
    n, m = dense.shape
    indptr = np.empty(n + 1, np.int64)
    nnz = _call('advocc_csr_indptr', _ptr(dense), n, m, _ptr(indptr), worker_threads())
    indices = np.empty(nnz, np.int64)
    _call('advocc_csr_indices', _ptr(dense), n, m, _ptr(indptr), _ptr(indices),
          worker_threads())
    return indptr, indices


__all__ = ['Chain', 'KernelBuildError', 'Tables', 'accumulate', 'contains', 'corridor_candidates',
           'cover', 'dense_to_csr', 'dls', 'frames', 'library', 'link_frames', 'line_sums',
           'min_plus']
