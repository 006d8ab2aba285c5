"""The attack, online (paper §IV-B; docs/design.md): ``attack`` runs the pipeline for one task.

Given a heatmap H, the scene E, the start ``q_init`` and a goal region G, place at most M
axis-aligned boxes of edge s under the constraints C1-C3, by the method asked (default
``task``), under the goal policy asked (default ``paper``). ``attack`` checks the request
(``attack.request.validate_request``, the task check of ``model.task_check`` included), then
runs the steps,
each a function from data to data in a module of its own, and gathers their statistics:

1. the task sample (``attack.task.task_sample``), when the method covers it or the policy is
   ``solvable`` (in the ``joint`` form with the direct motion when the scene leaves it free: the
   result says whether the boxes cut it, ``direct_motion_cut``);
2. the search region, C1-C3 (``attack.region.search_region``);
3. the goal policy (``attack.policy.apply_policy``; under ``solvable`` the witness and its
   choice; in the ``joint`` form with ``TaskOptions.exit_rays``, steps 3-5 run for each
   candidate witness and ``attack.exits.fewest_exits`` keeps one placement);
4. and 5. the method (``attack.methods.REGISTRY``): for ``task`` its objective
   (``attack.objective``, with the routes beside the kept witness: ``RoutesToCut``) and one
   greedy pass (``attack.greedy``); ``ours`` (the paper's heatmap-mass greedy), ``random``,
   ``pfa``, ``pfa++`` choose from the region their own way;
6. the verdict (``attack.solvable.judge``): ``goal_valid_fraction`` and whether the task keeps
   a solution. Its time is not attack time.

**No planner is queried here** (the paper's threat model): ``attack`` starts no process and
imports no planner. PFA and PFA++ are the exception by design: the planner is their method, and
their caller hands the planners in (``method_options``). The ``solvable`` policy and the
``certified`` verdict need the task's *witness* (a collision-free path from ``q_init`` into G on
the unattacked scene); it is data handed in (``witness=``), found once per task by the tool at
the edges with RRTConnect (``advocc_ros.attack.edges``: the CLI, the heatmap server, the audit,
the benchmark, the export), never by the victim. Without a witness, ``solvable`` is refused
(``NO_WITNESS``) and the verdict of the other policies is judged without one: ``goal blocked``
(the goal probe, IK only) or ``unknown``, never ``certified``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from typing import Any

import numpy as np

from advocc_ros.attack.exits import (ExitRays, GoalExits, close_exits, corridor_rays,
                                     fewest_exits, rays_cut, route_rays)
from advocc_ros.attack.methods import CONTEXT_METHODS, METHODS, REGISTRY, MethodContext
from advocc_ros.attack.policy import apply_policy
from advocc_ros.attack.region import search_region
from advocc_ros.attack.request import box_size, validate_request
from advocc_ros.attack.solvable import judge, witness_candidates
from advocc_ros.attack.task import TaskOptions, direct_motion_cut, task_sample
from advocc_ros.attack.types import (DEFAULT_METHOD, AttackConfig, AttackError, AttackResult,
                                     AttackStatus, Task, box_id)
from advocc_ros.heatmap import Heatmap, link_tables
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.collision import shared_world
from advocc_ros.model.scene import SceneObject, make_box

log = logging.getLogger(__name__)


def attack(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...] | list,
           q_init: np.ndarray, goal: GoalRegion, budget: int, method: str = DEFAULT_METHOD,
           cfg: AttackConfig = AttackConfig(), box_size_m: float | None = None,
           seed: int = 0, method_options: Any = None, goal_policy: str | None = None,
           certify: bool = True, witness: Any = None) -> AttackResult:
    """Place at most ``budget`` boxes for one task; starts no planner (module docstring).
    Never raises for a bad request: the result carries the status and message instead.

    ``method_options``: settings of a method (``advocc_ros.attack.pfa.PfaOptions``,
    ``advocc_ros.attack.task.TaskOptions``); ``goal_policy``: ``paper``, ``reachable`` or
    ``solvable`` (None or '': ``cfg.goal_policy``); ``witness``: the task's candidate witnesses
    (``planning.witness.Witness``, one or a sequence, found on the unattacked scene;
    ``advocc_ros.attack.edges`` finds them), required by ``solvable``; ``certify``: also say
    whether the task keeps a solution (``result.solvable``), judged with the witnesses
    (``certified`` needs one)."""
    link_tables(robot, heatmap.lut_pitch_m)  # model loading (~1 s once), not attack time
    t0 = time.perf_counter()
    s = box_size(cfg, box_size_m)
    policy = goal_policy or cfg.goal_policy
    base = dict(method=method, budget=int(budget) if isinstance(budget, (int, np.integer))
                else 0, box_size_m=s, goal_policy=policy, goal_form=getattr(goal, 'form', ''))
    objects = tuple(objects)
    witnesses = witness_candidates(witness)
    try:
        validate_request(heatmap, robot, objects, q_init, goal, budget, method, s, cfg, policy)
        task = Task(robot, objects, np.asarray(q_init, dtype=float), goal, policy)
        placed = place_boxes(heatmap, task, int(budget), method, cfg, s, seed, method_options,
                             witnesses)
    except AttackError as exc:
        return AttackResult(exc.status, str(exc), compute_s=time.perf_counter() - t0, **base)
    except (SceneError, RobotError) as exc:
        return AttackResult(AttackStatus.INVALID_REQUEST, str(exc),
                            compute_s=time.perf_counter() - t0, **base)
    compute_s = time.perf_counter() - t0
    # Step 6, the verdict: diagnostics, not attack time.
    verdict = judge(task, placed.obstacles, s, placed.witnesses, certify)
    result = AttackResult(placed.status, placed.message, placed.obstacles, placed.masses,
                          float(sum(placed.masses)), compute_s,
                          stats={**placed.stats, **verdict.stats},
                          goal_valid_fraction=verdict.goal_valid_fraction,
                          solvable=verdict.solvable,
                          witness=_judged_witness(placed.witnesses, verdict.solvable), **base)
    log.info('attack %s M=%d: %s, mass %.3f, %.1f ms, goal valid %s, %s', method, budget,
             result.status.value, result.total_mass, result.compute_s * 1e3,
             result.goal_valid_fraction,
             result.solvable.verdict if result.solvable else 'solvability not assessed')
    return result


@dataclasses.dataclass(frozen=True)
class Placed:
    """The boxes of steps 1-5, before the verdict."""

    status: AttackStatus
    message: str
    obstacles: tuple[SceneObject, ...]
    """Boxes ``adv_0``, ``adv_1``, ... in pick order."""
    masses: tuple[float, ...]
    stats: dict
    """Every step's statistics, gathered here."""
    witnesses: tuple
    """The candidate witnesses the verdict judges: under ``solvable`` the one kept."""


def place_boxes(heatmap: Heatmap, task: Task, budget: int, method: str, cfg: AttackConfig,
                box_size_m: float, seed: int, options: Any, witnesses: tuple) -> Placed:
    """Steps 1-5 of docs/design.md for a checked request: the task sample (when the method or
    the policy needs it), the search region, the goal policy (under ``solvable`` the witness
    and its choice), then the method (for ``task``: the objective and the greedy pass)."""
    if task.policy == 'solvable' and not witnesses:
        raise AttackError(AttackStatus.NO_WITNESS,
                          'the solvable policy needs the task\'s witness and none was given: '
                          'it keeps a witness path valid, and without one no attack can be '
                          'certified to keep a solution (the tool finds it on the unattacked '
                          'scene with RRTConnect: advocc_ros.attack.edges)')
    seed = int(seed) % 2 ** 64  # message seeds are int64 and may be < 0; numpy's are not
    stats: dict[str, Any] = {}
    sample = None
    if REGISTRY[method].needs_sample or task.policy == 'solvable':
        t = time.perf_counter()
        opts = options if isinstance(options, TaskOptions) else TaskOptions()
        sample = task_sample(task, opts, seed)                                  # step 1
        stats.update(sample.stats, task_sampling_ms=round((time.perf_counter() - t) * 1e3, 1))
    region = search_region(heatmap, task.robot, task.objects, task.q_init, task.goal, cfg,
                           box_size_m)                                          # step 2
    choice = None if sample is None else sample.choice

    def steps_3_to_5(kept: int | None = None, closing: ExitRays | None = None) -> tuple:
        policed = apply_policy(task, region, cfg, witnesses, choice, kept)      # step 3
        extra = {}
        if method in CONTEXT_METHODS:
            extra['context'] = MethodContext.of(task, options, with_rays(
                sample, closing, *routes.of(policed.witness)), policed)
        picks, rejected, *more = METHODS[method](policed.region, budget, seed, cfg,
                                                 **extra)                       # steps 4-5
        return policed, picks, rejected, more[0] if more else {}

    routes = RoutesToCut(task, options, witnesses, sample)

    def boxes(placement: tuple) -> tuple[SceneObject, ...]:
        return tuple(make_box(box_id(i), np.round(region.center_m(c), 9), (box_size_m,) * 3)
                     for i, (c, _) in enumerate(placement[1]))

    placement = steps_3_to_5()
    if tries_exits(task, method, options):
        exits = GoalExits(task, options.exit_rays)
        placement, free, exit_stats = fewest_exits(
            task, exits, witnesses, placement[0].stats.get('witness_kept', 0), placement,
            steps_3_to_5, boxes, cfg.victim_margin_m)
        kept = exit_stats['witness_kept_for_exits']
        placement, round_stats = close_exits(
            exits, placement, free,
            lambda closing: steps_3_to_5(kept, closing), boxes, options.exit_rounds)
        stats.update(exit_stats, **round_stats)
    policed, picks, rejected, method_stats = placement
    stats = {**region.stats, **policed.stats, **stats, **method_stats, 'rejected_picks': rejected}
    obstacles = boxes(placement)
    stats.update(routes.cut(policed.witness, obstacles))
    if sample is not None and sample.exits is not None:  # the direct motion was free
        stats['direct_motion_cut'] = direct_motion_cut(task, obstacles)
    status, message = AttackStatus.SUCCESS, f'placed {len(obstacles)} boxes'
    if len(obstacles) < budget:
        status = AttackStatus.PARTIAL
        message = stats.get('stop_reason') or (
            f'only {len(obstacles)} of {budget} boxes fit the search region '
            f'({stats.get("candidates", 0)} candidate centres)')
    kept = witnesses if policed.witness is None else (policed.witness,)
    return Placed(status, message, obstacles, tuple(float(m) for _, m in picks), stats, kept)


class RoutesToCut:
    """The routes beside the kept witness for the boxes to cut, rays of the objective's top
    tier (``TaskOptions.cut_routes``: the other candidate witnesses; ``corridor_routes``:
    paths shifted from the kept one), made once per kept witness."""

    def __init__(self, task: Task, options: Any, witnesses: tuple, sample):
        self.task, self.witnesses, self._made = task, witnesses, {}
        self.options = options if isinstance(options, TaskOptions) else TaskOptions()
        self.offsets = None if sample is None else sample.corridor_noise

    def of(self, kept) -> tuple[ExitRays | None, ExitRays | None]:
        """(the other candidates, the corridor routes) for the kept witness ``kept``."""
        if kept is None:
            return None, None
        key = kept.content_hash()
        if key not in self._made:
            robot = self.task.robot
            scene = shared_world(robot, [sh for o in self.task.objects for sh in o.shapes])
            self._made[key] = (
                route_rays(robot, self.witnesses, kept) if self.options.cut_routes else None,
                corridor_rays(scene, kept.configurations(robot), self.offsets)
                if self.offsets is not None else None)
        return self._made[key]

    def cut(self, kept, boxes: tuple[SceneObject, ...]) -> dict:
        """How many of the kept witness's routes ``boxes`` block (statistics)."""
        stats = {}
        for name, rays, asked in zip(('routes', 'corridor_routes'), self.of(kept),
                                     (self.options.cut_routes, self.offsets is not None)):
            if asked:
                count = 0 if rays is None else rays.count
                stats.update({name: count, f'{name}_cut': rays_cut(self.task.robot, rays, boxes)})
        return stats


def with_rays(sample, *more: ExitRays | None):
    """``sample`` with the rays of ``more`` (those not None: the exits to close, the routes
    beside the kept witness) joined to its own (``TaskSample.exits``, the objective's top
    tier). None stays None (a method without a sample)."""
    rays = [r for r in (() if sample is None else (sample.exits, *more)) if r is not None]
    if sample is None or not rays:
        return sample
    return dataclasses.replace(sample, exits=functools.reduce(ExitRays.join, rays))


def tries_exits(task: Task, method: str, options: Any) -> bool:
    """Whether step 3 is tried through steps 4-5 for each candidate witness
    (``attack.exits``): ``task`` under ``solvable`` in the ``joint`` form, with
    ``TaskOptions.exit_rays`` (one candidate: its exits counted, then closed in rounds)."""
    return (method == 'task' and task.policy == 'solvable' and task.goal.is_joint
            and isinstance(options, TaskOptions) and options.exit_rays > 0)


def _judged_witness(witnesses: tuple, solvable):
    """The witness a result reports: the one the verdict was proven with, else the first
    candidate."""
    if solvable is not None and solvable.witness is not None:
        return solvable.witness
    return witnesses[0] if witnesses else None


__all__ = ['Placed', 'RoutesToCut', 'attack', 'place_boxes', 'tries_exits', 'with_rays']
