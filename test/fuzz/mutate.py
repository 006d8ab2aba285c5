"""Seeded, structure-aware mutations: of parsed documents, of YAML text and of raw bytes.

A mutation starts from a valid input and breaks one thing at a time (a field's type, value or
presence; a header count; a byte range), which reaches deeper into a parser than random bytes.
Every function takes a ``random.Random`` and is deterministic given its state.
"""

from __future__ import annotations

import copy
import random
from typing import Any

NAN, INF = float('nan'), float('inf')

NUMBERS = [NAN, INF, -INF, 0, -0.0, -1, 1e-320, 1e308, -1e308, 10 ** 30, -10 ** 30, 2 ** 63,
           0.5, 3]
SCALARS = [None, True, False, '', 'x', 'world', '../../etc/passwd', 'ä' * 40, '1.0', '.nan',
           'box', 'mesh', 'cloud', 'panda_link0', 'panda_joint1', 'x' * 5000]
CONTAINERS = [[], {}, [0, 0, 0], [NAN] * 3, [-1, -1, -1], [1, 2], [1, 2, 3, 4, 5],
              [[0, 0, 0]] * 4, {'x': 1}, {'x': 0, 'y': 0, 'z': 0}, [[]], [{}], [None] * 3,
              [0.0] * 20_000]
KEYS = ['id', 'type', 'size', 'dims', 'file', 'pose', 'objects', 'bogus', 'points', 'resolution',
        'vertices', 'faces', 'start', 'goal', 'name', 'robot', 'operation', 'frame', '<<', '']

YAML_TOKENS = ['&a ', '*a', '*nope', '!!python/object/apply:os.system ["true"]', '!!binary x',
               '!!set {a, b}', '!!timestamp 2001-12-14', '!!float', '!!int', '{', '}', '[', ']',
               ': ', '\t', '---\n', '...\n', '%YAML 1.1\n', '\x00', '\ufeff', 'ä', '<<: *a',
               '? ', '- ', '.nan', '.inf', '-.inf', '1e999', '0x7fffffff', '~', '"', "'", '#',
               '|\n', '>\n', '\n  ', ',', '@', '`']


def nasty(rng: random.Random, like: Any = None) -> Any:
    """A replacement value: often one that looks like ``like`` but is wrong in a subtle way."""
    pool = rng.random()
    if isinstance(like, bool) or like is None:
        pass
    elif isinstance(like, (int, float)) and pool < 0.5:
        return rng.choice(NUMBERS + [like * rng.choice([-1, 1e9, 1e-9]), str(like), [like]])
    elif isinstance(like, str) and pool < 0.5:
        return rng.choice(['', like.upper(), like + 'x', like * 50, f'{like}\x00', 1, None])
    elif isinstance(like, list) and pool < 0.5:
        return rng.choice([like[:-1], like + like[-1:], like * 3, [like], list(reversed(like)),
                           [str(v) for v in like]] if like else [[None], [[]]])
    choice = rng.random()
    if choice < 0.4:
        return rng.choice(NUMBERS)
    if choice < 0.7:
        return rng.choice(SCALARS)
    return copy.deepcopy(rng.choice(CONTAINERS))


def _paths(doc: Any, prefix: tuple = ()):
    yield prefix
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from _paths(value, prefix + (key,))
    elif isinstance(doc, list):
        for i, value in enumerate(doc[:8]):
            yield from _paths(value, prefix + (i,))


def _at(doc: Any, path: tuple) -> Any:
    for key in path:
        doc = doc[key]
    return doc


def mutate_doc(rng: random.Random, doc: Any, edits: int | None = None) -> Any:
    """A copy of ``doc`` with 1-4 edits: replace, delete, add a key, grow, nest, swap types."""
    doc = copy.deepcopy(doc)
    for _ in range(edits or rng.randint(1, 4)):
        paths = list(_paths(doc))
        path = rng.choice(paths)
        if not path:
            doc = nasty(rng, doc) if rng.random() < 0.2 else doc
            continue
        parent, key = _at(doc, path[:-1]), path[-1]
        value = parent[key]
        action = rng.choice(['replace', 'replace', 'replace', 'delete', 'add', 'grow', 'nest',
                             'swap'])
        if action == 'replace':
            parent[key] = nasty(rng, value)
        elif action == 'delete':
            del parent[key]
        elif action == 'add' and isinstance(value, dict):
            value[rng.choice(KEYS)] = nasty(rng)
        elif action == 'grow' and isinstance(value, list) and value:
            parent[key] = value * rng.choice([2, 2, 50, 50, 1001])
        elif action == 'nest':
            parent[key] = [value] if rng.random() < 0.5 else {'value': value}
        elif action == 'swap' and isinstance(parent, dict) and len(parent) > 1:
            other = rng.choice([k for k in parent if k != key] or [key])
            parent[key], parent[other] = parent[other], value
    return doc


def mutate_bytes(rng: random.Random, raw: bytes, max_edits: int = 6) -> bytes:
    """``raw`` truncated, bit-flipped, with ranges deleted, duplicated or overwritten."""
    b = bytearray(raw)
    for _ in range(rng.randint(1, max_edits)):
        op = rng.choice(['flip', 'flip', 'truncate', 'delete', 'dup', 'zero', 'ff', 'insert'])
        n = len(b)
        at = rng.randrange(n) if n else 0
        span = min(n - at, rng.choice([1, 2, 4, 16, 256]))
        if op == 'flip' and n:
            b[at] ^= 1 << rng.randrange(8)
        elif op == 'truncate':
            del b[at:]
        elif op == 'delete':
            del b[at:at + span]
        elif op == 'dup':
            b[at:at] = b[at:at + span]
        elif op in ('zero', 'ff'):
            b[at:at + span] = (b'\x00' if op == 'zero' else b'\xff') * span
        elif op == 'insert':
            b[at:at] = rng.choice([b'\x00', b'\xff' * 8, b'\n', b'-1', b'nan', b'9' * 20])
    return bytes(b)


def mutate_text(rng: random.Random, text: str) -> str:
    """YAML text with grammar tokens (anchors, tags, brackets, tabs) inserted or lines cut."""
    lines = text.splitlines(keepends=True) or ['\n']
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(lines))
        op = rng.choice(['insert', 'insert', 'drop', 'dup', 'indent', 'cut'])
        if op == 'insert':
            line = lines[i]
            at = rng.randint(0, len(line))
            lines[i] = line[:at] + rng.choice(YAML_TOKENS) + line[at:]
        elif op == 'drop' and len(lines) > 1:
            del lines[i]
        elif op == 'dup':
            lines.insert(i, lines[i])
        elif op == 'indent':
            lines[i] = rng.choice([' ', '  ', '\t', '    ']) + lines[i]
        elif op == 'cut':
            lines = lines[:i + 1]
            lines[-1] = lines[-1][:rng.randint(0, len(lines[-1]))]
    return ''.join(lines)


def yaml_bomb(levels: int = 9) -> str:
    """A few hundred bytes of YAML whose aliases expand to 10^levels numbers."""
    node = '&l0 [' + ', '.join(['0.1'] * 10) + ']'
    for i in range(1, levels):
        node = f'&l{i} [{node}, ' + ', '.join([f'*l{i - 1}'] * 9) + ']'
    return node


def hostile_yaml(rng: random.Random, key: str) -> str:
    """Whole documents no mutation of a valid one would reach: bombs, cycles, deep nesting."""
    return rng.choice([
        f'{key}: {yaml_bomb(rng.randint(3, 9))}\n',
        f'{key}: &o [*o]\n',
        f'{key}: ' + '[' * 3000 + ']' * 3000 + '\n',
        f'{key}: ' + '{a: ' * 2000 + '1' + '}' * 2000 + '\n',
        '!!python/object/apply:os.system ["true"]\n',
        f'{key}: !!python/name:os.system\n',
        '\x00\x01\x02',
        '',
        '---\n---\n',
        f'{key}:\n' + '  - 0.0\n' * 50_000,
    ])
