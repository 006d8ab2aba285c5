"""PFA's optimiser: continuous samples decoded into valid placements, and CMA-ES over them.

Generic over the objective (``Objective``), so the optimiser's own behaviour is testable without
a planner; ``advocc_ros.attack.pfa`` scores placements with planner queries. The choices (snap to
the nearest valid candidate, Lamarckian repair, the rescored top, the stopping rules) are
explained in that module's docstring.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Protocol, Sequence

import numpy as np
from cmaes import CMA
from scipy.spatial import cKDTree

# --------------------------------------------------------------------------------------------
# Decoding continuous samples to valid placements

Placement = tuple[int, ...]
"""Rows of :attr:`Decoder.index` (candidate voxels), in box order."""


class Decoder:
    """Maps points of [0, 1]^(3M) to placements of valid candidates (snap + d_min repair)."""

    def __init__(self, centers_m: np.ndarray, d_min_m: float,
                 accept: Callable[[int], bool] | None = None, neighbours: int = 32):
        self.centers = np.asarray(centers_m, dtype=float).reshape(-1, 3)
        self.lo = self.centers.min(axis=0) if len(self.centers) else np.zeros(3)
        self.extent = np.maximum(
            (self.centers.max(axis=0) if len(self.centers) else np.zeros(3)) - self.lo, 1e-9)
        self.tree = cKDTree(self.centers) if len(self.centers) else None
        self.d_min, self._accept, self.k = d_min_m, accept, neighbours
        self._checked: dict[int, bool] = {}
        self.rejected = 0

    def normalise(self, rows: Sequence[int]) -> np.ndarray:
        return ((self.centers[list(rows)] - self.lo) / self.extent).ravel()

    def accept(self, row: int) -> bool:
        if row not in self._checked:
            ok = self._accept is None or bool(self._accept(row))
            self._checked[row] = ok
            self.rejected += not ok
        return self._checked[row]

    def _fits(self, row: int, chosen: list[int]) -> bool:
        if chosen and np.min(np.linalg.norm(self.centers[chosen] - self.centers[row],
                                            axis=1)) < self.d_min - 1e-9:
            return False
        return self.accept(row)

    def nearest_valid(self, point_m: np.ndarray, chosen: list[int]) -> int | None:
        n = len(self.centers)
        k = min(self.k, n)
        while True:
            _, rows = self.tree.query(point_m, k=k)
            for row in np.atleast_1d(rows):
                if self._fits(int(row), chosen):
                    return int(row)
            if k >= n:
                return None
            k = min(4 * k, n)

    def decode(self, x: np.ndarray) -> Placement:
        chosen: list[int] = []
        if self.tree is None:
            return ()
        for p in np.asarray(x, dtype=float).reshape(-1, 3):
            row = self.nearest_valid(self.lo + np.clip(p, 0.0, 1.0) * self.extent, chosen)
            if row is not None:
                chosen.append(row)
        return tuple(chosen)

    def random_placement(self, m: int, rng: np.random.Generator) -> Placement:
        """Up to ``m`` valid candidates in a seeded random order (the CMA-ES start)."""
        chosen: list[int] = []
        for row in rng.permutation(len(self.centers)):
            if len(chosen) == m:
                break
            if self._fits(int(row), chosen):
                chosen.append(int(row))
        return tuple(chosen)


# --------------------------------------------------------------------------------------------
# The optimiser (generic over the objective, so its own behaviour is testable)

class Objective(Protocol):
    """Scores placements (higher = better) under a budget of placements."""

    def affordable(self) -> int:
        """How many more placements can be scored."""

    def __call__(self, placements: list[Placement]) -> list[float]:
        """Scores of ``placements`` (at most ``affordable()`` of them)."""


@dataclasses.dataclass
class OptimiseResult:
    best: Placement
    best_score: float
    scored: int
    """Distinct placements scored."""
    generations: int
    """Generations told to CMA-ES."""
    stopped: str
    """'budget', 'converged' or 'idle'."""
    history: list[tuple[Placement, float]]
    """Every distinct placement scored, in order."""


def optimise(decoder: Decoder, objective: Objective, budget: int, seed: int,
             sigma0: float = 0.2, population_size: int | None = None,
             max_idle_generations: int = 20, rescore_top: int = 0) -> OptimiseResult:
    """CMA-ES over placements of ``budget`` boxes (see the module docstring).

    ``rescore_top`` placements' worth of budget (at most a third of it, so small budgets
    still search) is kept back; at the end the best-scored placements are scored again and
    their two scores averaged before the best is chosen.
    """
    rng = np.random.default_rng(seed)
    start = decoder.random_placement(budget, rng)
    m = len(start)
    if m == 0:
        return OptimiseResult((), -math.inf, 0, 0, 'no candidates', [])
    scores: dict[tuple[int, ...], float] = {}
    history: list[tuple[Placement, float]] = []
    # A start with fewer than M boxes (few candidates): optimise the boxes that fit.
    opt = CMA(mean=np.clip(decoder.normalise(start), 1e-6, 1 - 1e-6), sigma=sigma0,
              bounds=np.tile([0.0, 1.0], (3 * m, 1)), seed=int(seed) % (2 ** 31),
              population_size=population_size)
    rescore_top = min(rescore_top, objective.affordable() // 3)
    generations, stopped = _generations(opt, decoder, objective, scores, history, m,
                                        rescore_top, max_idle_generations)
    if rescore_top and history:
        _rescore(objective, scores, history, rescore_top)
    # Ties go to the latest: later generations are better informed, and an early tie is more
    # likely a lucky draw of a noisy score (K queries) than a real blocker.
    best, best_score = max(reversed(history), key=lambda h: scores[_key(h[0])]) if history \
        else (start, -math.inf)
    best_score = scores.get(_key(best), best_score)
    return OptimiseResult(best, best_score, len(scores), generations, stopped, history)


def _key(p: Placement) -> tuple[int, ...]:
    """A placement's rows sorted: the same boxes in another order score the same."""
    return tuple(sorted(p))


def _generations(opt: CMA, decoder: Decoder, objective: Objective, scores: dict,
                 history: list, m: int, rescore_top: int,
                 max_idle_generations: int) -> tuple[int, str]:
    """Ask, score the new placements, tell, until the budget (less ``rescore_top``) is spent,
    CMA-ES converges or ``max_idle_generations`` bring nothing new; fills ``scores`` and
    ``history`` and returns the generations told and why they stopped."""
    generations = idle = 0
    while True:
        xs = [opt.ask() for _ in range(opt.population_size)]
        placements = [decoder.decode(x) for x in xs]
        new, complete = _score_new(placements, objective, scores, history, rescore_top)
        if not complete:
            return generations, 'budget'  # exhausted inside a generation: it is not told
        idle = 0 if new else idle + 1
        opt.tell(_told(opt, decoder, placements, scores, m))
        generations += 1
        if opt.should_stop():
            return generations, 'converged'
        if idle >= max_idle_generations:
            return generations, 'idle'
        if objective.affordable() <= rescore_top:
            return generations, 'budget'


def _score_new(placements: list[Placement], objective: Objective, scores: dict, history: list,
               rescore_top: int) -> tuple[int, bool]:
    """Score the generation's placements not scored before, as many as the budget (less
    ``rescore_top``) affords; returns how many were new and whether all of them were scored."""
    new = list(dict.fromkeys(_key(p) for p in placements if _key(p) not in scores))
    affordable = max(objective.affordable() - rescore_top, 0)
    todo = [next(p for p in placements if _key(p) == k) for k in new[:affordable]]
    if todo:
        for p, s in zip(todo, objective(todo)):
            scores[_key(p)] = s
            history.append((p, s))
    return len(new), len(new) <= affordable


def _told(opt: CMA, decoder: Decoder, placements: list[Placement], scores: dict,
          m: int) -> list[tuple[np.ndarray, float]]:
    """The generation as CMA-ES takes it: each placement re-encoded (Lamarckian repair) with its
    negated score (CMA-ES minimises)."""
    told = []
    for p in placements:
        x = decoder.normalise(p)
        if len(x) < 3 * m:  # fewer boxes fit than the start had: pad with the mean
            x = np.concatenate([x, opt.mean[len(x):]])
        told.append((x, -scores[_key(p)]))
    return told


def _rescore(objective: Objective, scores: dict, history: list, rescore_top: int) -> None:
    """Score the best-scored placements again (as many as ``rescore_top`` and the budget allow)
    and keep the mean of their two scores, appended to ``history``."""
    top = sorted(scores, key=scores.get, reverse=True)[:min(rescore_top, objective.affordable())]
    placement = {_key(p): p for p, _ in history}
    for k, s in zip(top, objective([placement[k] for k in top])):
        scores[k] = (scores[k] + s) / 2
        history.append((placement[k], scores[k]))


__all__ = ['Decoder', 'Objective', 'OptimiseResult', 'Placement', 'optimise']
