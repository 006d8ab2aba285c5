"""Planner-in-the-loop baselines PFA and PFA++ (paper §V-A "Baselines"; docs/design.md).

PFA (Wu et al., ICRA 2024) optimises where to put M obstacles by querying a motion planner and
keeping the placements that make it fail. Their text is not available here, so this module
implements the baseline as our paper describes it; every choice is listed below.

What is optimised. M axis-aligned boxes of edge s, in the same search region as Ours and
Random (:func:`advocc_ros.attack.search_region`, constraints C1-C3): every centre is a valid
candidate voxel centre that passes the exact coal check, and centres are >= d_min apart. So
the three methods differ only in how they choose among the same candidates.

Objective. A placement is scored by K planner queries (``queries_per_placement``, default 3)
in the scene plus the boxes: ``score = failures + g`` with ``g = max(0, 1 - L0 / L)``, where L
is the mean joint-space path length of the successful queries (OMPL's simplified path) and L0
the same over K queries of the unattacked scene. g lies in [0, 1), so it only breaks ties
between equal failure counts (lexicographic: failure rate first, then detour). Any status other
than SUCCESS is a failure (timeout, goal in collision, no IK solution): the planner did not
deliver a plan, which is what the attack is for. An internal error (a crashed planning worker)
says nothing about the boxes: asked again with another seed; a second one stops the attack.
Repeated placements reuse their score (no queries are spent twice on one set of boxes).

Optimiser. CMA-ES from the maintained ``cmaes`` package (0.13.1) in 3M continuous dimensions:
each box's centre normalised to [0, 1] over the candidates' bounding box (box bounds given to
CMA-ES), initial mean = M distinct seeded random candidates, sigma0 = 0.2, population size the
library default 4 + floor(3 ln 3M). A sample is decoded box by box: the nearest candidate
centre (k-d tree) that passes the exact check and keeps d_min from the boxes already placed.
CMA-ES is told the decoded (snapped) point, not the raw sample (Lamarckian repair), so its
distribution follows placements that exist. The last ``rescore_top`` (3) placements' worth of
queries (at most a third of the budget) is kept back: the best-scored placements are queried K more
times and their two scores averaged, because the top of many 3-query scores is often a lucky draw.
The result is the best placement after that (the latest on ties).
No restarts: with a few hundred queries there is no budget for them.

Budget. ``queries`` (Q) counts every planner call, the K baseline queries included, and is
never exceeded: a generation is evaluated only as far as whole placements (K queries each)
still fit; a partly evaluated generation is not told to CMA-ES and ends the run. The run also
ends when CMA-ES reports convergence or when ``max_idle_generations`` generations in a row
decode only to placements already scored. Stats report the queries made and the time taken.

PFA vs PFA++. PFA queries OMPL RRT-Connect with an **exact goal pose**: the goal region's
centre with MoveIt's default pose-goal tolerances (1e-4 m, 1e-3 rad), i.e. what a
``setPoseTarget`` request asks for. We chose a (near-)zero region over a single IK joint
configuration because it is a plain plan request, so the same queries run through the planner
shims' ``~/plan`` service; IK still picks configurations along the arm's self-motion, as MoveIt
does for a pose goal. PFA++ queries the *victim* planner (``planner_id``: rrtconnect, prmstar,
bkpiece1) with the task's **goal region**, as the victim will be evaluated. For RRT-Connect
the two differ only in the goal (pose vs region); the paper treats them as equivalent and its
tables show PFA++ as "--" for RRT. ``pfa++`` with ``rrtconnect`` still runs as defined (goal
region), it is not aliased to ``pfa``.

Planner queries go through :class:`QueryPlanner`: a thread-safe callable
``(q_start, obstacles, goal, planner_id, time_budget_s, seed) -> PlanResult`` with a
``workers`` attribute (how many calls may run at once). ``advocc_ros.planning.LocalPlanners``
backs it with one or more ``Planner`` worker processes; an orchestrator can back it with
planner-shim services instead. Per-query budgets are short (``query_time_s``, default
1 s) because the optimiser needs many queries; the victim is still evaluated with its own
budget (5 s). A failing query costs its whole budget, and a successful one nearly so (OMPL's
simplifier uses what the budget leaves), so online time ~ Q * query_time_s / workers.
PRM* always spends its whole budget (it keeps optimising, as in MoveIt) unless the backend's
``PlanningConfig.stop_at_first_solution`` says otherwise; we query it as deployed.

Reproducibility. The CMA-ES stream, initial mean and query seeds derive from ``seed``; OMPL's
own randomness and its wall-clock budgets do not, so two runs agree only while the planner
outcomes agree (the optimiser itself is deterministic given the outcomes; see the tests).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
import math
import threading
import time
from typing import Callable, Protocol

import numpy as np

from advocc_ros.attack.coverage import Coverage
from advocc_ros.attack.methods import MethodContext, register_method
from advocc_ros.attack.pfa_search import Decoder, Placement, optimise
from advocc_ros.attack.region import SearchRegion
from advocc_ros.attack.types import AttackConfig, AttackError, AttackStatus, box_id
from advocc_ros.limits import MAX_PLANNER_QUERIES
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject, make_box
from advocc_ros.planning.types import REQUEST_ERRORS, PlanResult, PlanStatus, planner_class_name

log = logging.getLogger(__name__)

PFA_PLANNER = 'rrtconnect'
EXACT_POSITION_TOL_M = 1e-4
"""MoveIt's default pose-goal position tolerance (MoveGroupInterface)."""
EXACT_ORIENTATION_TOL_RAD = 1e-3
"""MoveIt's default pose-goal orientation tolerance."""
RETRY_SEED_OFFSET = 2 ** 30  # a query asked again uses seed + this: no seed of the run's own


@dataclasses.dataclass(frozen=True)
class PfaConfig:
    """Optimiser settings; defaults are ours (the PFA paper's are not available)."""

    queries: int = 150
    """Q: planner calls in total, the K baseline queries included (never exceeded)."""
    queries_per_placement: int = 3
    """K: planner queries per scored placement."""
    query_time_s: float = 1.0
    """Time budget of one optimiser query [s] (the victim's own budget is 5 s)."""
    planner_id: str = PFA_PLANNER
    """Planner PFA++ queries (the victim); PFA always queries RRT-Connect."""
    sigma0: float = 0.2
    """Initial CMA-ES step, in units of the candidates' bounding box."""
    population_size: int | None = None
    """CMA-ES population; None: the library default 4 + floor(3 ln 3M)."""
    max_idle_generations: int = 20
    """Stop after this many generations in a row that decode only to scored placements."""
    rescore_top: int = 3
    """Placements re-scored with K more queries at the end (reserved from the budget): with
    K = 3 noisy queries the top score is often a lucky draw; the pooled score is not."""

    def __post_init__(self):
        checks = {'queries': 2 * self.queries_per_placement <= self.queries
                  <= MAX_PLANNER_QUERIES,
                  'queries_per_placement': self.queries_per_placement >= 1,
                  'query_time_s': 0 < self.query_time_s <= 600,
                  'sigma0': 0 < self.sigma0 <= 1,
                  'population_size': self.population_size is None or self.population_size >= 2,
                  'max_idle_generations': self.max_idle_generations >= 1,
                  'rescore_top': self.rescore_top >= 0}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f'PFA parameter {name}={getattr(self, name)!r} is out of range'
                                 + (f' (needs 2 K .. {MAX_PLANNER_QUERIES}: baseline + at '
                                    'least one placement)' if name == 'queries' else ''))
        if planner_class_name(self.planner_id) is None:
            raise ValueError(f'unknown planner {self.planner_id!r}')


class QueryPlanner(Protocol):
    """Planner backend of the optimiser: thread-safe, ``workers`` calls may run at once."""

    workers: int

    def __call__(self, q_start: np.ndarray, obstacles: tuple[SceneObject, ...],
                 goal: GoalRegion, planner_id: str, time_budget_s: float, seed: int
                 ) -> PlanResult:
        """Plan in the backend's scene plus ``obstacles``."""


@dataclasses.dataclass(frozen=True)
class PfaOptions:
    """What ``attack(..., method_options=...)`` passes to PFA/PFA++."""

    planner: QueryPlanner
    config: PfaConfig = PfaConfig()
    progress: Callable[[int, int], None] | None = None
    """Called with (queries done, query budget) after each query."""


def exact_goal(goal: GoalRegion) -> GoalRegion:
    """The goal region's centre pose as a pose goal (MoveIt's default tolerances)."""
    return dataclasses.replace(goal, position_tolerance_m=(EXACT_POSITION_TOL_M,) * 3,
                               orientation_tolerance_rad=(EXACT_ORIENTATION_TOL_RAD,) * 3)


# --------------------------------------------------------------------------------------------
# Planner objective

class _PlannerObjective:
    """Failure count + path-length tie-break over K planner queries per placement."""

    def __init__(self, planner: QueryPlanner, q_init: np.ndarray, goal: GoalRegion,
                 planner_id: str, cfg: PfaConfig, boxes: Callable[[Placement], tuple],
                 seed: int, progress: Callable[[int, int], None] | None):
        self.planner, self.q_init, self.goal = planner, q_init, goal
        self.planner_id, self.cfg, self.boxes = planner_id, cfg, boxes
        self.seed, self.progress = int(seed), progress
        self.used = 0
        self.done = 0
        self.planner_time_s = 0.0
        self.statuses: dict[str, int] = {}
        self.retried = 0
        self.baseline_length: float | None = None
        self.baseline_failures = 0
        self._lock = threading.Lock()
        self._pool = concurrent.futures.ThreadPoolExecutor(max(1, int(planner.workers)))

    def close(self) -> None:
        self._pool.shutdown(wait=True)

    def affordable(self) -> int:
        return (self.cfg.queries - self.used) // self.cfg.queries_per_placement

    def _ask(self, obstacles: tuple, seed: int) -> PlanResult:
        res = self.planner(self.q_init, obstacles, self.goal, self.planner_id,
                           self.cfg.query_time_s, seed)
        with self._lock:
            self.planner_time_s += res.planning_time_s
            self.statuses[res.status.name] = self.statuses.get(res.status.name, 0) + 1
        return res

    def _query(self, obstacles: tuple, seed: int) -> PlanResult:
        res = self._ask(obstacles, seed)
        retry = res.status == PlanStatus.INTERNAL_ERROR
        if retry:
            log.warning('PFA query failed internally (%s); asked again', res.message)
            res = self._ask(obstacles, (seed + RETRY_SEED_OFFSET) % (2 ** 31))
        with self._lock:
            self.retried += retry
            self.done += 1
            if self.progress is not None:
                self.progress(self.done, self.cfg.queries)
        return res

    def _run(self, obstacle_sets: list[tuple]) -> list[list[PlanResult]]:
        """K queries per obstacle set, all in parallel over the backend's workers."""
        K = self.cfg.queries_per_placement
        if self.used + K * len(obstacle_sets) > self.cfg.queries:
            raise RuntimeError('PFA: query budget exceeded (bug)')
        jobs = []
        for i, obstacles in enumerate(obstacle_sets):
            for j in range(K):
                seed = (self.seed * 1_000_003 + self.used + i * K + j) % (2 ** 31)
                jobs.append(self._pool.submit(self._query, obstacles, seed))
        self.used += len(jobs)
        results = [f.result() for f in jobs]
        for r in results:
            if r.status in REQUEST_ERRORS:
                raise AttackError(AttackStatus.INVALID_REQUEST, f'PFA query refused: {r.message}')
            if r.status == PlanStatus.INTERNAL_ERROR:
                raise AttackError(AttackStatus.INTERNAL_ERROR, 'PFA: the planner failed '
                                  f'internally twice on one query: {r.message}')
        return [results[i * K:(i + 1) * K] for i in range(len(obstacle_sets))]

    def baseline(self) -> None:
        (results,) = self._run([()])
        self.baseline_failures = sum(not r.success for r in results)
        self.baseline_length = _mean_length(results)

    def score(self, results: list[PlanResult]) -> float:
        fails = sum(not r.success for r in results)
        length = _mean_length(results)
        g = 0.0
        if length and self.baseline_length:
            g = max(0.0, 1.0 - self.baseline_length / length)
        return fails + min(g, 1.0 - 1e-9)

    def __call__(self, placements: list[Placement]) -> list[float]:
        return [self.score(r) for r in self._run([self.boxes(p) for p in placements])]


def _mean_length(results: list[PlanResult]) -> float | None:
    lengths = [r.stats.get('path_length_rad') for r in results if r.success]
    lengths = [x for x in lengths if x is not None]
    return float(np.mean(lengths)) if lengths else None


# --------------------------------------------------------------------------------------------
# Selectors

def _select(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig,
            context: MethodContext, exact: bool) -> tuple[list, int]:
    name = 'pfa' if exact else 'pfa++'
    options = context.options
    if not isinstance(options, PfaOptions):
        raise AttackError(AttackStatus.UNKNOWN_METHOD,
                          f'method {name!r} queries a planner, and this caller provides none '
                          '(pass method_options=PfaOptions(planner=...); `advocc attack '
                          f'--method {name}` starts local planners)')
    pcfg = options.config
    planner_id = PFA_PLANNER if exact else pcfg.planner_id
    goal = exact_goal(context.goal) if exact else context.goal
    t0 = time.perf_counter()
    cand = np.argwhere(region.candidates)
    centers = region.center_m(cand).reshape(-1, 3)
    decoder = Decoder(centers, region.d_min_m, lambda row: region.accept(cand[row]))
    s = region.box_size_m

    def boxes(p: Placement) -> tuple[SceneObject, ...]:
        return tuple(make_box(box_id(i), np.round(centers[row], 9), (s, s, s))
                     for i, row in enumerate(p))

    objective = _PlannerObjective(options.planner, np.asarray(context.q_init, float), goal,
                                  planner_id, pcfg, boxes, seed, options.progress)
    try:
        if len(cand):
            objective.baseline()
        result = optimise(decoder, objective, budget, seed, pcfg.sigma0, pcfg.population_size,
                          pcfg.max_idle_generations, pcfg.rescore_top)
    finally:
        objective.close()
    K = pcfg.queries_per_placement
    best_fail = math.floor(result.best_score) / K if result.history else None
    stats = {name: {
        'planner': planner_id, 'goal': 'exact pose' if exact else 'goal region',
        'queries': objective.used, 'query_budget': pcfg.queries, 'queries_per_placement': K,
        'query_time_s': pcfg.query_time_s, 'workers': int(options.planner.workers),
        'placements_scored': result.scored, 'generations': result.generations,
        'stopped': result.stopped, 'statuses': objective.statuses,
        'internal_errors_retried': objective.retried,
        'baseline_failure_rate': objective.baseline_failures / K if len(cand) else None,
        'baseline_path_length_rad': objective.baseline_length, 'best_failure_rate': best_fail,
        'best_path_increase': (result.best_score - math.floor(result.best_score)
                               if result.history else None),
        'planner_time_s': round(objective.planner_time_s, 3),
        'optimise_s': round(time.perf_counter() - t0, 3)}}
    if objective.baseline_failures == K and len(cand):
        log.warning('%s: the unattacked task failed all %d baseline queries (%s, %.2g s); the '
                    'objective is saturated: raise the query time', name, K, planner_id,
                    pcfg.query_time_s)
    log.info('%s: %d queries, %d placements, best failure rate %s, %.1f s', name,
             objective.used, result.scored, best_fail, time.perf_counter() - t0)
    coverage = Coverage(region.weights, region.candidates, region.k,
                        region.d_min_m / region.grid.voxel_m)
    return ([(cand[row], coverage.cover(cand[row])) for row in result.best], decoder.rejected,
            stats)


def _select_pfa(region, budget, seed, cfg, context):
    return _select(region, budget, seed, cfg, context, exact=True)


def _select_pfa_pp(region, budget, seed, cfg, context):
    return _select(region, budget, seed, cfg, context, exact=False)


register_method('pfa', _select_pfa)
register_method('pfa++', _select_pfa_pp)

__all__ = ['EXACT_ORIENTATION_TOL_RAD', 'EXACT_POSITION_TOL_M', 'PFA_PLANNER', 'PfaConfig',
           'PfaOptions', 'QueryPlanner', 'exact_goal']
