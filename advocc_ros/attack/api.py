"""Online phase: adversarial occupancy maximization (paper §IV-B, Algorithm 1; docs/design.md).

Given a heatmap H, the scene E, the start ``q_init`` and a goal region G, place at most M
axis-aligned boxes of edge s that cover as much heatmap mass as possible.

**No planner is queried here** (the paper's threat model): ``attack`` starts no process and
imports no planner. PFA and PFA++ are the exception by design: the planner is their method, and
their caller hands the planners in (``method_options``). The ``solvable`` policy and the
``certified`` verdict need the task's *witness* (a collision-free path from ``q_init`` into G on
the unattacked scene); it is data handed in (``witness=``), found once per task by the tool at
the edges with one RRTConnect run (``advocc_ros.attack.edges``: the CLI, the heatmap server, the
audit, the benchmark, the export), never by the victim. Without a witness, ``solvable`` is
refused (``NO_WITNESS``) and the verdict of the other policies is judged without one: ``goal
blocked`` (the goal probe, IK only) or ``unknown``, never ``certified``.

Search region (constraints C1-C3), all on the heatmap's voxel grid (box centres are voxel
centres, ``U(c)`` = voxels whose centres lie in the closed box):

- corridor: centre within ``r_corr`` of the segment from the tool point at ``q_init`` to the
  goal-region centre; ``H(c) > 0``; ``c`` in V_free (V_free of the file AND not inside the
  current scene: robot-only heatmaps need this, scene-conditioned ones get it for free);
- the box fits: no occupied (non-free) voxel centre inside the box, i.e. ``U(c)`` is in V_free;
- clearance ``d_safe`` from the robot body at ``q_init`` and from G's position box (the
  paper's C3). With ``AttackConfig.protect_goal_hand`` (off by default), also from the hand
  (every link on the end-effector's joint) at one goal configuration found by a deterministic
  damped-least-squares IK from ``q_init`` to the goal centre (skipped, and reported as
  ``stats['goal_ik']``, when the IK does not converge). By default nothing keeps a goal pose
  free: boxes may block every goal configuration, which ``goal_valid_fraction`` reports and
  the goal policy ``reachable`` prevents.

The voxel tests use an exact lattice "box distance transform" (distance from each candidate's
box to the nearest protected voxel centre), which can only over-estimate true clearances, so
it never drops a valid candidate; every box a method picks is then checked exactly with coal
(scene: no contact; robot at ``q_init``, goal box, hand at goal: distance >= d_safe) and a
failing candidate is discarded and the method picks again ("lazy" verification). What the
greedy then guarantees is stated and proved in ``docs/greedy.md``.

Greedy: box sums of the uncovered mass by separable shift-adds over a window around the
corridor; after each pick only the sums within 2k voxels of it change and are recomputed
locally. Random baseline: candidates in a seeded random order under the same constraints.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from advocc_ros.attack.goals import GoalGuard, goal_samples
from advocc_ros.attack.solvable import (CERTIFICATE, WitnessGuard, assess, choose_witness,
                                        witness_bodies, witness_candidates)
from advocc_ros.attack.methods import CONTEXT_METHODS, METHODS, MethodContext, load_method
from advocc_ros.attack.region import search_region
from advocc_ros.attack.types import (BOX_ID, DEFAULT_METHOD, POLICIES, AttackConfig,
                                     AttackError, AttackResult, AttackStatus, box_id)
from advocc_ros.heatmap import Heatmap, link_tables
from advocc_ros.kinematics.goal_batch import goal_pocket, task_goals
from advocc_ros.model.collision import shared_world
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.scene import SceneObject, make_box
from advocc_ros.model.task_check import TaskProblem, check_task

log = logging.getLogger(__name__)

_TASK_STATUS = {TaskProblem.START_INVALID: AttackStatus.INVALID_START,
                TaskProblem.START_IN_COLLISION: AttackStatus.START_IN_COLLISION,
                TaskProblem.GOAL_INVALID: AttackStatus.INVALID_LINK,
                TaskProblem.GOAL_IN_COLLISION: AttackStatus.INVALID_GOAL}


# --------------------------------------------------------------------------------------------
# Entry point

def box_size(cfg: AttackConfig, requested_m: float | None) -> float:
    """The box edge of a request [m]: ``requested_m``, or ``cfg.box_size_m`` for None or 0."""
    return cfg.box_size_m if requested_m is None or requested_m == 0 else float(requested_m)


def validate_request(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...],
                     q_init: np.ndarray, goal: GoalRegion, budget: int, method: str,
                     box_size_m: float, cfg: AttackConfig, goal_policy: str | None = None
                     ) -> None:
    """Raise ``AttackError`` with the status and a clear message for a bad request (the task
    check of ``model.task_check`` included: start limits, self and scene collision by pair)."""
    if not load_method(method):
        raise AttackError(AttackStatus.UNKNOWN_METHOD,
                          f'unknown attack method {method!r}; known: {sorted(METHODS)}')
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) \
            or not 1 <= budget <= cfg.max_budget:
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'budget must be an integer in 1..{cfg.max_budget}, got {budget!r}')
    if not (np.isfinite(box_size_m) and 0 < box_size_m <= cfg.max_box_m):
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'box size must be in (0, {cfg.max_box_m}] m, got {box_size_m!r}')
    expected = heatmap.meta.get('robot_hash')
    if expected is not None and expected != robot.hash:
        raise AttackError(AttackStatus.ROBOT_MISMATCH,
                          f'the heatmap was built for robot {expected}, not {robot.hash}')
    _check_policy(goal_policy or cfg.goal_policy, method)
    if not any(goal.position_tolerance_m) and not any(goal.orientation_tolerance_rad):
        raise AttackError(AttackStatus.INVALID_GOAL,
                          'goal region is empty: every tolerance is 0 (an unset message?); '
                          'give position half-extents and orientation tolerances')
    _check_object_ids(objects)
    fault = check_task(robot, objects, q_init, goal)
    if fault is not None:
        raise AttackError(_TASK_STATUS[fault.problem], fault.message)


def _check_policy(policy: str, method: str) -> None:
    if policy not in POLICIES:
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'unknown goal policy {policy!r}; known: {list(POLICIES)}')
    if policy != 'paper' and method in ('pfa', 'pfa++'):
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'goal policy {policy} applies to the coverage methods, not '
                          f'{method} (its planner queries already see a blocked goal)')


def _check_object_ids(objects: tuple[SceneObject, ...]) -> None:
    """Ids name objects (MoveIt replaces an object on ADD with its id): repeated ids, or the
    ids the attack gives its boxes, would make the scene with the boxes ambiguous."""
    ids = [o.id for o in objects]
    repeated = sorted({i for i in ids if ids.count(i) > 1})
    if repeated:
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'object ids repeat: {repeated}; each collision object needs its own')
    taken = sorted(i for i in ids if BOX_ID.fullmatch(i))
    if taken:
        raise AttackError(AttackStatus.INVALID_REQUEST,
                          f'object ids {taken} are the names of the attack\'s boxes (adv_0, '
                          'adv_1, ...); remove the boxes of an earlier attack or rename them')


def attack(heatmap: Heatmap, robot: RobotModel, objects: tuple[SceneObject, ...] | list,
           q_init: np.ndarray, goal: GoalRegion, budget: int, method: str = DEFAULT_METHOD,
           cfg: AttackConfig = AttackConfig(), box_size_m: float | None = None,
           seed: int = 0, method_options: Any = None, goal_policy: str | None = None,
           certify: bool = True, witness: Any = None) -> AttackResult:
    """Place at most ``budget`` boxes for one task; starts no planner (module docstring).
    Never raises for a bad request: the result carries the status and message instead.

    ``method_options``: settings of a method (``advocc_ros.attack.pfa.PfaOptions``,
    ``advocc_ros.attack.task.TaskOptions``); ``goal_policy``: ``paper``, ``reachable`` or
    ``solvable`` (None or '': ``cfg.goal_policy``); ``witness``: the task's witness
    (``planning.witness.Witness``, found on the unattacked scene; ``advocc_ros.attack.edges``
    finds it), required by ``solvable``; ``certify``: also say whether the task keeps a
    solution (``result.solvable``), judged with the witness (``certified`` needs one)."""
    link_tables(robot, heatmap.lut_pitch_m)  # model loading (~1 s once), not attack time
    t0 = time.perf_counter()
    s = box_size(cfg, box_size_m)
    policy = goal_policy or cfg.goal_policy
    base = dict(method=method, budget=int(budget) if isinstance(budget, (int, np.integer))
                else 0, box_size_m=s, goal_policy=policy, goal_form=getattr(goal, 'form', ''))
    objects = tuple(objects)
    try:
        validate_request(heatmap, robot, objects, q_init, goal, budget, method, s, cfg, policy)
        q_init = np.asarray(q_init, dtype=float)
        region = search_region(heatmap, robot, objects, q_init, goal, cfg, s)
        if policy == 'reachable':  # the goal samples are part of the attack: timed
            region.guard = GoalGuard(goal_samples(robot, objects, goal), s,
                                     cfg.reachable_fraction)
        elif policy == 'solvable':
            witness, touching = _kept_witness(robot, objects, goal, region,
                                              _required(witness))
            region.guard = WitnessGuard(witness_bodies(robot, shared_world(robot), witness), s,
                                        CERTIFICATE.guard_margin_m + cfg.victim_margin_m)
            region.guard.prune(region, touching)
        extra = {}
        if method in CONTEXT_METHODS:
            extra['context'] = MethodContext(robot, objects, q_init, goal, method_options)
        seed = int(seed) % 2 ** 64  # message seeds are int64 and may be < 0; numpy's are not
        picks, rejected = METHODS[method](region, int(budget), seed, cfg, **extra)
    except AttackError as exc:
        return AttackResult(exc.status, str(exc), compute_s=time.perf_counter() - t0, **base)
    except (SceneError, RobotError) as exc:
        return AttackResult(AttackStatus.INVALID_REQUEST, str(exc),
                            compute_s=time.perf_counter() - t0, **base)
    obstacles = tuple(make_box(box_id(i), np.round(region.center_m(c), 9), (s, s, s))
                      for i, (c, _) in enumerate(picks))
    masses = tuple(float(m) for _, m in picks)
    stats = dict(region.stats, rejected_picks=rejected)
    if len(obstacles) < budget:
        status = AttackStatus.PARTIAL
        message = region.stats.get('stop_reason') or (
            f'only {len(obstacles)} of {budget} boxes fit the search region '
            f'({region.stats.get("candidates", 0)} candidate centres)')
    else:
        status, message = AttackStatus.SUCCESS, f'placed {len(obstacles)} boxes'
    compute_s = time.perf_counter() - t0
    # Diagnostics, not attack time: how many goal poses the boxes leave (samples cached per
    # task, so a task's attacks are judged on the same samples), and whether a solution is left.
    t1 = time.perf_counter()
    samples = goal_samples(robot, objects, goal)
    fraction = samples.valid_fraction(
        np.array([o.shapes[0].pose.position_m for o in obstacles]), s)
    stats['goal_check_ms'] = round((time.perf_counter() - t1) * 1e3, 3)
    stats['goal_samples'] = len(samples.Q)
    stats['goal_samples_time_cap_hit'] = samples.time_cap_hit
    solvable = None
    if certify:
        t1 = time.perf_counter()
        solvable = assess(robot, objects, obstacles, goal, witness, q_init)
        stats['solvable_ms'] = round((time.perf_counter() - t1) * 1e3, 3)
    result = AttackResult(status, message, obstacles, masses, float(sum(masses)), compute_s,
                          stats=stats, goal_valid_fraction=fraction, solvable=solvable,
                          witness=_judged_witness(witness, solvable), **base)
    log.info('attack %s M=%d: %s, mass %.3f, %.1f ms, goal valid %s, %s', method, budget,
             status.value, result.total_mass, result.compute_s * 1e3, fraction,
             solvable.verdict if solvable else 'solvability not assessed')
    return result


def _judged_witness(witness, solvable):
    """The witness a result reports: the one the verdict was proven with, else the kept (or
    first) candidate."""
    if solvable is not None and solvable.witness is not None:
        return solvable.witness
    candidates = witness_candidates(witness)
    return candidates[0] if candidates else None


def _kept_witness(robot: RobotModel, objects, goal: GoalRegion, region, witnesses):
    """(the candidate the ``solvable`` policy keeps, its lattice mask or None): see
    ``attack.solvable.choose_witness``, on the task's goal sample; the choice in
    ``region.stats``."""
    if len(witnesses) == 1:
        return witnesses[0], None
    if goal.is_joint:  # the goal is kept: what the witness shields is the goal's pocket
        Q_goal = goal_pocket(robot, shared_world(robot, [sh for o in objects for sh in o.shapes]),
                             goal)
    else:
        Q_goal = task_goals(robot, objects, goal).Q
    kept, shielded, touching = choose_witness(robot, shared_world(robot), region, witnesses,
                                              Q_goal)
    region.stats.update(witness_candidates=len(witnesses), witness_kept=kept,
                        witness_shielded=shielded)
    return witnesses[kept], touching


def _required(witness) -> tuple:
    """The ``solvable`` policy's candidate witnesses (a witness or a sequence of them);
    ``AttackError`` (``NO_WITNESS``) without one."""
    witnesses = witness_candidates(witness)
    if not witnesses:
        raise AttackError(AttackStatus.NO_WITNESS,
                          'the solvable policy needs the task\'s witness and none was given: '
                          'it keeps a witness path valid, and without one no attack can be '
                          'certified to keep a solution (the tool finds it on the unattacked '
                          'scene with RRTConnect: advocc_ros.attack.edges)')
    return witnesses
