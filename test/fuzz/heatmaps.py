"""Malformed heatmap files: corrupted and truncated zips, arrays of the wrong dtype, shape or
value, lying ``.npy`` headers, shuffled members, and pickled object arrays (which must be
refused: one of them creates a directory if anything ever unpickles it).
"""

from __future__ import annotations

import io
import json
import os
import pathlib
import random
import zipfile

import numpy as np

from fuzz.mutate import NUMBERS, mutate_bytes

DTYPES = [np.float32, np.int64, np.int8, np.uint8, bool, np.complex128, '>f8', '<U3', np.float16]


class _Smuggled:
    """Unpickling this object runs ``os.makedirs(path)``: proof that a pickle was loaded."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return os.makedirs, (self.path,)


def _members(raw: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(raw)) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, array, allow_pickle=True)  # object arrays: hostile inputs
    return buf.getvalue()


def _zip(members: list[tuple[str, bytes]], compress: bool) -> bytes:
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, 'w', method) as zf:
        for name, data in members:
            zf.writestr(name, data)
    return buf.getvalue()


def _crafted(rng: random.Random, key: str, array: np.ndarray) -> np.ndarray:
    """``array`` made wrong: another dtype or shape, bad values, or something else entirely."""
    op = rng.choice(['dtype', 'shape', 'values', 'scalar', 'empty', 'special'])
    if op == 'dtype':
        return array.astype(rng.choice(DTYPES))
    if op == 'shape':
        return array.reshape(-1)[:max(0, array.size - rng.choice([0, 1, 7]))]
    if op == 'values' and array.dtype.kind in 'fiu' and array.size:
        out = array.astype(float).copy()
        out.flat[rng.randrange(out.size)] = rng.choice([np.nan, np.inf, -np.inf, -1.0, 1e308])
        return out
    if op == 'scalar':
        return np.array(rng.choice([v for v in NUMBERS if abs(v) < 2 ** 63]))
    if op == 'empty':
        return np.zeros((0,) * rng.randint(1, 3))
    return {
        'shape': lambda: np.array(rng.choice([[10 ** 6] * 3, [-1, 2, 2], [0, 0, 0], [2, 2],
                                              [2 ** 62, 2, 2]])),
        'meta_json': lambda: np.frombuffer(rng.choice([
            b'[' * 100_000 + b']' * 100_000, b'{"a": ' * 50_000 + b'1' + b'}' * 50_000,
            b'\xff\xfe', b'null', b'[1]', b'"x"', b'{"robot_hash": 1}', b'{' * 3, b'1e999999',
            b'{"params": []}', b'{"params": {"robot_only": "maybe"}}']), np.uint8),
        'voxel_m': lambda: np.array(rng.choice([0.0, -0.02, np.nan, 1e-300, 1e300])),
        'origin_m': lambda: np.array(rng.choice([[np.nan, 0, 0], [1e308] * 3, [0, 0]])),
        'format_version': lambda: np.array(rng.choice([2, 0, -1, 1.5, 2 ** 62])),
    }.get(key, lambda: np.full(array.shape, rng.choice([-1.0, np.nan])))()


def _lying_header(rng: random.Random, npy: bytes) -> bytes:
    """An ``.npy`` whose header's shape, dtype or order says something its data is not."""
    end = npy.index(b'\n') + 1
    header = npy[:end].decode('latin1')
    fake = rng.choice([
        ("'shape': (", "'shape': (100000000, "), ("'shape': (", "'shape': (-3, "),
        ("'descr': '<f8'", "'descr': '|O'"), ("'descr': '<f8'", "'descr': '<f16'"),
        ("'descr': '|b1'", "'descr': '<f8'"), ("'fortran_order': False", "'fortran_order': 1"),
        ("'descr'", "'dtype'"), ("{", "{'x': __import__('os'), "), ("'shape': (", "'shape': ("),
    ])
    header = header.replace(*fake, 1)
    return header.encode('latin1') + npy[end:]


def generate(rng: random.Random, raw: bytes, canary: pathlib.Path
             ) -> tuple[bytes, bool, bool]:
    """(file bytes, must be refused, carries the canary pickle) from the valid file ``raw``."""
    members = _members(raw)
    mode = rng.choice(['bytes', 'bytes', 'array', 'array', 'array', 'header', 'members',
                       'pickle', 'canary'])
    compress = rng.random() < 0.5
    if mode == 'bytes':
        return mutate_bytes(rng, raw, 8), False, False
    names = sorted(members)
    name = rng.choice(names)
    key = name[:-4]
    if mode == 'array':
        arrays = {k[:-4]: np.load(io.BytesIO(v)) for k, v in members.items()}
        arrays[key] = _crafted(rng, key, arrays[key])
        picked = arrays[key].dtype == object
        return _zip([(k + '.npy', _npy(v)) for k, v in arrays.items()], compress), picked, False
    if mode == 'header':
        members[name] = _lying_header(rng, members[name])
        return _zip(sorted(members.items()), compress), False, False
    if mode == 'members':
        items = sorted(members.items())
        op = rng.choice(['drop', 'dup', 'rename', 'extra', 'dir'])
        i = rng.randrange(len(items))
        if op == 'drop':
            del items[i]
        elif op == 'dup':
            items.append(items[i])
        elif op == 'rename':
            items[i] = (rng.choice(['../' + items[i][0], items[i][0][:-4], 'x.npy', ' ']),
                        items[i][1])
        elif op == 'extra':
            items.append(('extra.npy', _npy(np.zeros(3))))
        else:
            items.append(('values.npy/', b''))
        return _zip(items, compress), False, False
    payload = _Smuggled(str(canary)) if mode == 'canary' else rng.choice([{'a': 1}, 'x', None])
    arr = np.empty(1, dtype=object)
    arr[0] = payload
    members[name] = _npy(arr)
    return _zip(sorted(members.items()), compress), True, mode == 'canary'


def robot_hash_of(raw: bytes) -> str | None:
    """The robot hash in a valid heatmap file's metadata."""
    meta = np.load(io.BytesIO(_members(raw)['meta_json.npy']))
    return json.loads(meta.tobytes().decode()).get('robot_hash')


def check(heatmap) -> str | None:
    """Why an accepted heatmap is not usable, or None."""
    grid = heatmap.grid
    if not (np.all(np.isfinite(grid.origin_m)) and np.isfinite(grid.voxel_m)
            and grid.voxel_m > 0):
        return f'accepted grid {grid}'
    if heatmap.values.shape != tuple(grid.shape) or not np.all(np.isfinite(heatmap.values)):
        return 'accepted values that do not fit the grid'
    if not isinstance(heatmap.meta, dict):
        return 'metadata is not a mapping'
    return None
