"""Step 5 of the attack (method ``task``): one lazy greedy pass over the objective
(docs/design.md; what it guarantees: docs/greedy.md).

Up to M candidate boxes, each the one whose uncovered rows weigh the most, at least ``d_min``
from the earlier picks; each pick is checked exactly (``SearchRegion.accept``: coal, and the goal
policy's guard) before it is kept, and a refused one is dropped ("lazy" verification). Ties go to
the lowest candidate, so the pass is deterministic; budgets nest (budget M's boxes are the first
M of budget M + 1's).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import sparse

from advocc_ros.attack.region import SearchRegion
from advocc_ros.attack.types import AttackConfig


@dataclasses.dataclass(frozen=True)
class GreedyPass:
    """The boxes one pass placed."""

    picks: list
    """(window index (3,), marginal reported weight) of each box, in pick order."""
    rejected: int
    """Picks the exact check refused."""
    covered: np.ndarray
    """bool per objective row: covered by the picks."""
    candidates: int
    """Candidates the pass chose from."""


def greedy_pass(objective, region: SearchRegion, budget: int, cfg: AttackConfig) -> GreedyPass:
    """The greedy of ``objective`` (``attack.objective.Objective``) over ``region``'s
    candidates, each pick checked by ``region.accept``."""
    cand = np.argwhere(region.candidates)
    centers = region.center_m(cand) if len(cand) else np.zeros((0, 3))
    picks, rejected = greedy_configurations(
        objective.cover, objective.weights, centers, budget, region.d_min_m,
        lambda j: region.accept(cand[j]), cfg.max_rejections, feasible=objective.feasible)
    masses, covered = marginal_masses(objective.cover, objective.reported, picks)
    return GreedyPass([(cand[j], m) for j, m in zip(picks, masses)], rejected, covered,
                      len(cand))


def greedy_configurations(cover: sparse.spmatrix | np.ndarray, weights: np.ndarray,
                          centers_m: np.ndarray, budget: int, d_min_m: float, accept=None,
                          max_rejections: int = AttackConfig.max_rejections,
                          bonus: np.ndarray | None = None, feasible=None) -> tuple[list[int], int]:
    """Greedy budgeted maximum coverage: up to ``budget`` candidate columns of ``cover``
    (configurations x candidates, 0/1), >= ``d_min_m`` apart, maximizing the ``weights`` of
    the configurations covered (each once) plus a modular ``bonus`` per candidate; and how
    many candidates ``accept`` refused. Picks with no gain left are not made. ``feasible()``,
    if given, returns a mask of candidates still allowed (called before every pick).
    Ties go to the lowest column, so the result is deterministic."""
    rows = sparse.csr_matrix(cover, dtype=np.float64)
    cols = rows.tocsc()
    weights = np.asarray(weights, dtype=np.float64)
    score = rows.T @ weights
    if bonus is not None:
        score = score + bonus  # modular: every box earns its own, picks never change it
    alive = np.ones(rows.shape[1], dtype=bool)
    uncovered = np.ones(rows.shape[0], dtype=bool)
    picks: list[int] = []
    rejected = 0
    while len(picks) < budget and alive.any():
        if feasible is not None:
            alive &= feasible()
            if not alive.any():
                break
        j = int(np.argmax(np.where(alive, score, -np.inf)))
        if score[j] <= 0:
            break  # nothing left to cover: a further box would be no attack
        if accept is not None and not accept(j):
            alive[j] = False
            rejected += 1
            if rejected > max_rejections:
                break
            continue
        hit = cols.indices[cols.indptr[j]:cols.indptr[j + 1]]
        newly = hit[uncovered[hit]]
        if len(newly):
            score -= rows[newly].T @ weights[newly]
            uncovered[newly] = False
        picks.append(j)
        alive &= np.linalg.norm(centers_m - centers_m[j], axis=1) >= d_min_m
    return picks, rejected


def marginal_masses(cover: sparse.csr_matrix, w: np.ndarray, picks: list[int]
                    ) -> tuple[list[float], np.ndarray]:
    """Each pick's newly covered weight ``w`` (in pick order) and the rows covered in the end."""
    covered = np.zeros(cover.shape[0], dtype=bool)
    masses = []
    cols = cover.tocsc()
    for j in picks:
        hit = cols.indices[cols.indptr[j]:cols.indptr[j + 1]]
        newly = hit[~covered[hit]]
        masses.append(float(w[newly].sum()))
        covered[newly] = True
    return masses, covered


__all__ = ['GreedyPass', 'greedy_configurations', 'greedy_pass', 'marginal_masses']
