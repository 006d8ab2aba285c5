"""Malformed PLY and PCD point clouds: a valid file of a few random points, then its header
lines (counts, types, sizes, field names, encoding) and/or its body (values, bytes) broken.
"""

from __future__ import annotations

import io
import random
import struct

import numpy as np

from fuzz.mutate import mutate_bytes

_BAD_NUMBERS = ['nan', 'inf', '-inf', '1e999', 'x', '', '0x10', '-0', '1e-400', '9' * 40]


def _points(rng: random.Random) -> np.ndarray:
    n = rng.choice([1, 2, 5, 40, 200])
    scale = rng.choice([0.1, 1.0, 1.0, 1e6, 1e30])
    return np.array([[rng.uniform(-scale, scale) for _ in range(3)] for _ in range(n)])


def _mutate_header(rng: random.Random, lines: list[str], counts: list[int]) -> list[str]:
    """Break one to three header lines: their numbers, words, order or presence."""
    lines = list(lines)
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(lines))
        words = lines[i].split()
        op = rng.choice(['number', 'number', 'word', 'drop', 'dup', 'swap', 'extra'])
        if op == 'number' and words:
            k = rng.randrange(len(words))
            words[k] = str(rng.choice([0, -1, 1, 2 ** 31, 10 ** 9, 2 ** 64, 'x', '1.5',
                                       *(c + d for c in counts for d in (-1, 1))]))
        elif op == 'word' and words:
            words[rng.randrange(len(words))] = rng.choice(
                ['double', 'int', 'uchar', 'list', 'bogus', 'F', 'U', 'I', '8', '3', 'q', 'rgb',
                 'binary_middle_endian', 'binary_compressed', 'ascii', 'x', 'z', ''])
        elif op == 'drop' and len(lines) > 1:
            del lines[i]
            continue
        elif op == 'dup':
            lines.insert(i, lines[i])
        elif op == 'swap' and len(lines) > 1:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == 'extra':
            words += [rng.choice(['x', '1', 'float', 'F 4'])]
        lines[i] = ' '.join(words)
    return lines


def _mutate_ascii_body(rng: random.Random, rows: list[str]) -> list[str]:
    rows = list(rows)
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(rows))
        words = rows[i].split()
        op = rng.choice(['value', 'value', 'drop_value', 'extra_value', 'drop_row', 'dup_row'])
        if op == 'value' and words:
            words[rng.randrange(len(words))] = rng.choice(_BAD_NUMBERS)
        elif op == 'drop_value' and words:
            words.pop()
        elif op == 'extra_value':
            words.append('0')
        elif op == 'drop_row' and len(rows) > 1:
            del rows[i]
            continue
        elif op == 'dup_row':
            rows.insert(i, rows[i])
        rows[i] = ' '.join(words)
    return rows


def _assemble(rng: random.Random, header: list[str], counts: list[int], body: bytes,
              rows: list[str] | None) -> bytes:
    """Header and body, each left valid or broken, joined; sometimes raw bytes on top."""
    r = rng.random()
    if r < 0.35:
        header = _mutate_header(rng, header, counts)
    elif r < 0.6 and rows is not None:
        body = ('\n'.join(_mutate_ascii_body(rng, rows)) + '\n').encode()
    elif r < 0.8:
        body = mutate_bytes(rng, body)
    else:
        header = _mutate_header(rng, header, counts)
        body = mutate_bytes(rng, body)
    out = ('\n'.join(header) + '\n').encode() + body
    return mutate_bytes(rng, out, 3) if rng.random() < 0.1 else out


def ply(rng: random.Random) -> bytes:
    """A PLY cloud (ascii or binary, float or double, with or without colour and faces)."""
    pts = _points(rng)
    fmt = rng.choice(['ascii', 'binary_little_endian', 'binary_big_endian'])
    ptype = rng.choice(['float', 'double'])
    colour = rng.random() < 0.3
    faces = len(pts) >= 3 and rng.random() < 0.2
    header = ['ply', f'format {fmt} 1.0', 'comment fuzz', f'element vertex {len(pts)}',
              f'property {ptype} x', f'property {ptype} y', f'property {ptype} z']
    header += ['property uchar red'] if colour else []
    header += ['element face 1', 'property list uchar int vertex_indices'] if faces else []
    header += ['end_header']
    rows = [' '.join(f'{v:.9g}' for v in p) + (' 255' if colour else '') for p in pts]
    if fmt == 'ascii':
        body = ('\n'.join(rows + (['3 0 1 2'] if faces else [])) + '\n').encode()
        rows = rows + (['3 0 1 2'] if faces else [])
    else:
        end = '<' if fmt.endswith('little_endian') else '>'
        f = 'f' if ptype == 'float' else 'd'
        buf = io.BytesIO()
        for p in pts:
            buf.write(struct.pack(f'{end}3{f}', *p) + (b'\xff' if colour else b''))
        if faces:
            buf.write(struct.pack(f'{end}B3i', 3, 0, 1, 2))
        body, rows = buf.getvalue(), None
    return _assemble(rng, header, [len(pts)], body, rows)


def pcd(rng: random.Random) -> bytes:
    """A PCD cloud (ascii, binary or binary_compressed; x y z, sometimes with intensity)."""
    from pypcd4 import Encoding, PointCloud
    pts = _points(rng)
    encoding = rng.choice([Encoding.ASCII, Encoding.BINARY, Encoding.BINARY_COMPRESSED])
    if rng.random() < 0.3:
        data = np.column_stack([pts, np.ones(len(pts))]).astype(np.float32)
        cloud = PointCloud.from_points(data, ('x', 'y', 'z', 'intensity'),
                                       (np.float32,) * 4)
    else:
        cloud = PointCloud.from_xyz_points(pts.astype(np.float32))
    buf = io.BytesIO()
    cloud.save(buf, encoding=encoding)
    raw = buf.getvalue()
    end = raw.index(b'\nDATA ')
    end = raw.index(b'\n', end + 1) + 1
    header = raw[:end].decode('ascii').splitlines()
    body = raw[end:]
    rows = body.decode('ascii').splitlines() if encoding == Encoding.ASCII else None
    return _assemble(rng, header, [len(pts)], body, rows)
