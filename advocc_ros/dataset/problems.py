"""The problems of a MotionBenchMaker data set: discovery, the train/test split and the seeded
order in which ``--limit`` takes problems of each family.

A data set folder holds one folder per family (``box_panda/``, ...), each with
``sceneNNNN.yaml`` + ``requestNNNN.yaml`` pairs, as MotionBenchMaker publishes them
(KavrakiLab/ompl-workshop ``problems/``: 7 Panda families x 100). The split is fixed by the
problem number, never by a draw: problems 0001-0040 of each family are ``train`` (they choose
every setting), 0041-0100 are ``test`` (they only report).
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib
import re
from collections.abc import Callable

FAMILIES = ('bookshelf_small_panda', 'bookshelf_tall_panda', 'bookshelf_thin_panda',
            'box_panda', 'cage_panda', 'table_pick_panda', 'table_under_pick_panda')
"""MotionBenchMaker's seven Panda families, as its folders are named."""
FAMILY_SUFFIX = '_panda'
"""A family may be named without it on the command line (``box`` for ``box_panda``)."""
TRAIN_LAST = 40
"""Problems 1..TRAIN_LAST of every family are the train split, the rest the test split."""
SPLITS = ('train', 'test', 'all')
SCENE_FILE = re.compile(r'scene(\d{4})\.yaml')


class DatasetError(ValueError):
    """Input the user can fix: a missing folder, an unknown family or split, a bad setting."""


@dataclasses.dataclass(frozen=True)
class Problem:
    """One problem: its family folder's name, its number and its two files (the request may be
    missing; the job then refuses the problem and says so)."""

    family: str
    index: int
    scene: pathlib.Path
    request: pathlib.Path

    @property
    def name(self) -> str:
        """``NNNN``, the problem's folder name in the output."""
        return f'{self.index:04d}'

    @property
    def key(self) -> str:
        """``family/NNNN``: unique within a data set."""
        return f'{self.family}/{self.name}'

    @property
    def split(self) -> str:
        return split_of(self.index)


def split_of(index: int) -> str:
    """``train`` for problems 1..TRAIN_LAST, else ``test``."""
    return 'train' if 1 <= index <= TRAIN_LAST else 'test'


def family_folders(root: pathlib.Path) -> dict[str, pathlib.Path]:
    """The folders under ``root`` that hold at least one ``sceneNNNN.yaml``, by name."""
    return {d.name: d for d in sorted(root.iterdir())
            if d.is_dir() and any(SCENE_FILE.fullmatch(f.name) for f in d.iterdir())}


def resolve_families(available: dict[str, pathlib.Path], names: list[str] | None) -> list[str]:
    """The folder names ``names`` mean (``box`` or ``box_panda``), in the given order; every
    available family when ``names`` is empty. ``DatasetError`` for an unknown one."""
    if not names:
        return list(available)
    out = []
    for name in names:
        match = next((f for f in (name, name + FAMILY_SUFFIX) if f in available), None)
        if match is None:
            raise DatasetError(f'unknown family {name!r}; the problems folder has: '
                               f'{", ".join(available) or "none"}')
        if match not in out:
            out.append(match)
    return out


def discover(root: str | pathlib.Path, families: list[str] | None = None) -> list[Problem]:
    """Every problem of ``families`` (default: all) under ``root``, by family then number."""
    root = pathlib.Path(root)
    if not root.is_dir():
        raise DatasetError(f'{root}: no such problems folder')
    available = family_folders(root)
    if not available:
        raise DatasetError(f'{root}: no family folders with sceneNNNN.yaml files (expected '
                           f'e.g. {root}/box_panda/scene0001.yaml)')
    problems = []
    for family in resolve_families(available, families):
        folder = available[family]
        for path in sorted(folder.iterdir()):
            m = SCENE_FILE.fullmatch(path.name)
            if m:
                problems.append(Problem(family, int(m.group(1)), path,
                                        folder / f'request{m.group(1)}.yaml'))
    return problems


def seeded_order(problems: list[Problem], seed: int = 0) -> list[Problem]:
    """``problems`` ranked by a hash of ``seed``, the family and the number: a seeded order
    in which each problem's place depends on nothing else, so the order of any subset (a split,
    a folder with fewer problems) is the order of the whole restricted to it."""
    def rank(p: Problem) -> bytes:
        return hashlib.sha256(f'{seed}/{p.family}/{p.index}'.encode()).digest()
    return sorted(problems, key=rank)


def select(problems: list[Problem], split: str = 'all', limit: int | None = None,
           seed: int = 0, posable: Callable[[Problem], bool] | None = None) -> list[Problem]:
    """The problems of ``split``, family by family, each family in its seeded order
    (``seeded_order``); with ``limit``, the first ``limit`` of each family, or with ``posable``
    the first ``limit`` that it poses and those before them that it does not (a job refuses
    them: the selection says how many the goal form cannot pose). The same seed takes the same
    first N for every larger limit (a resumed build with a larger ``--limit`` builds a
    superset), whatever else the folder holds."""
    if split not in SPLITS:
        raise DatasetError(f'--split {split!r}: expected one of {", ".join(SPLITS)}')
    if limit is not None and limit < 1:
        raise DatasetError(f'--limit must be >= 1, got {limit}')
    chosen = []
    for family in dict.fromkeys(p.family for p in problems):
        pool = [p for p in problems if p.family == family and split in ('all', p.split)]
        chosen += _first(seeded_order(pool, seed), limit, posable)
    return chosen


def _first(ordered: list[Problem], limit: int | None,
           posable: Callable[[Problem], bool] | None) -> list[Problem]:
    """The shortest prefix of ``ordered`` that holds ``limit`` problems ``posable`` accepts
    (all of them: any problem) or, short of that, all of ``ordered``."""
    if limit is None:
        return ordered
    if posable is None:
        return ordered[:limit]
    taken, posed = [], 0
    for problem in ordered:
        if posed == limit:
            break
        taken.append(problem)
        posed += bool(posable(problem))
    return taken


__all__ = ['DatasetError', 'FAMILIES', 'Problem', 'SPLITS', 'TRAIN_LAST', 'discover',
           'resolve_families', 'seeded_order', 'select', 'split_of']
