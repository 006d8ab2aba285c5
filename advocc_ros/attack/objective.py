"""Step 4 of the attack (method ``task``): the objective, which configurations each candidate box
covers and what covering them is worth (docs/design.md).

A box covers a configuration when it holds a voxel the robot occupies there
(``attack.configurations``: a sparse 0/1 cover matrix, configurations x candidates). Rows:

- rays, one row each, covered when a box covers one of their states: under the ``joint`` form
  the direct motion from the start when the scene leaves it free (``attack.task.direct_motion``)
  and, with ``TaskOptions.exit_rounds``, the goal's exits (``attack.exits``), the RRT steps from
  the goal a placement left free; under ``solvable`` the routes beside the kept witness, with
  ``TaskOptions.cut_routes`` the witness search's other candidates (``attack.exits.route_rays``)
  and with ``corridor_routes`` paths shifted from the witness (``attack.exits.corridor_rays``);
- the goal tier (the task sample's goal configurations), each the same weight: every plan ends
  in the goal set, and what the boxes leave of the sample is the share of goals a planner can
  still draw;
- the same goal configurations reached one voxel deep into a box: among boxes that cover the
  same samples, the deeper one also blocks the unsampled goal configurations near them;
- the passage: the sample's approaches and, under the ``solvable`` policy, the tube around the
  kept witness (its guard states plus the sample's offsets), weighted by the paper's w(q).

One objective, lexicographic through its weights: a ray outweighs all goal configurations, a
goal configuration all deep contacts, a deep contact all passage configurations. Every plan
ends in the goal set, so the boxes first cut it to the sliver the policy must leave (under
``solvable``, around the witness's end, which the witness search places where planners rarely
sample), then narrow the passage.
It is a weighted coverage, monotone and submodular, maximised by one lazy greedy pass
(``attack.greedy``; guarantees in docs/greedy.md), so budgets nest. Under the ``reachable``
policy the goal set is no target: the rows are the passage alone, and candidates that would leave
too few goal samples valid are filtered out before every pick (``goal_filter``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np
from scipy import sparse

from advocc_ros.attack.configurations import cover_matrix
from advocc_ros.attack.exits import ExitRays
from advocc_ros.attack.greedy import greedy_pass
from advocc_ros.attack.methods import MethodContext, register_method
from advocc_ros.attack.policy import GoalGuard
from advocc_ros.attack.region import SearchRegion
from advocc_ros.attack.task import THREADS
from advocc_ros.attack.types import AttackConfig
from advocc_ros.heatmap import placement_arrays, sample_weights
from advocc_ros.model.collision import CollisionWorld, shared_world

WEIGHT_FLOOR = 1e-3
"""Smallest goal weight the lexicographic scaling is exact for (see
:func:`lexicographic_weights`)."""


@dataclasses.dataclass(frozen=True)
class Objective:
    """What the greedy pass maximises: the rows of ``cover`` it covers, weighted."""

    cover: sparse.csr_matrix
    """(configurations, candidates) 0/1: the box at candidate j covers configuration i."""
    weights: np.ndarray
    """The greedy's weight of each row (tiers scaled lexicographically)."""
    reported: np.ndarray
    """Each configuration's own weight, counted once (the masses a result reports)."""
    goal_rows: int
    """The goal tier's rows, first after the exit rows (0 when the goal set is no target)."""
    passage_rows: int
    """The last rows: approaches and tube."""
    feasible: Callable[[], np.ndarray] | None = None
    """Candidates still allowed, asked before every pick (``reachable``), or None."""
    exit_rows: int = 0
    """The first rows, before the goal tier: rays to close (the direct motion, the goal's
    exits)."""


def lexicographic_weights(*tiers: np.ndarray) -> np.ndarray:
    """The tiers' weights (top first) in one vector, each tier scaled so that one of its rows
    outweighs every row below it together: the greedy then ranks candidates tier by tier. The
    last tier keeps its weights, and the order of weights within a tier is kept. Exact when every
    weight of a scaled tier is at least :data:`WEIGHT_FLOOR`; below it the scale is capped
    (larger factors would round the lower tiers out of the scores)."""
    scaled, below = [], 0.0
    for k, w in enumerate(reversed(tiers)):
        w = np.asarray(w, dtype=np.float64)
        if k:
            w = w * (1.0 + below) / max(float(w.min(initial=1.0)), WEIGHT_FLOOR)
        scaled.append(w)
        below += float(w.sum())
    return np.concatenate(scaled[::-1])


def goal_filter(guard: GoalGuard, sample_cover: sparse.csr_matrix) -> Callable[[], np.ndarray]:
    """Candidates that keep enough of the guard's goal samples valid by the lattice estimate
    (``sample_cover``: samples x candidates; the guard's exact check still follows); asked
    before every pick, it follows the samples the guard still counts valid."""
    def feasible() -> np.ndarray:
        if not len(guard.valid):
            return np.ones(sample_cover.shape[1], dtype=bool)
        blocked = sample_cover.T @ guard.valid.astype(np.float64)  # valid samples each blocks
        left = (guard.valid.sum() - blocked) / len(guard.valid)
        return left >= guard.min_fraction - 1e-12
    return feasible


def tube_samples(world: CollisionWorld, states: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Collision-free configurations (k <= len(noise), nq) within the joint limits: witness
    states spread evenly along the path plus the offsets ``noise`` (one row each)."""
    if not len(noise) or not len(states):
        return np.zeros((0, world.robot.nq))
    base = states[np.linspace(0, len(states) - 1, len(noise)).round().astype(int)]
    Q = base + noise
    Q = Q[np.all((Q >= world.robot.lower) & (Q <= world.robot.upper), axis=1)]
    return Q[~world.collisions_batch(Q, THREADS)] if len(Q) else Q


def task_objective(context: MethodContext, region: SearchRegion) -> Objective:
    """The objective of the module docstring for ``region``'s candidates; the one place the
    goal policy decides the rows (``reachable``: the passage alone)."""
    robot, sample, policed = context.robot, context.sample, context.policed
    world = shared_world(robot, [sh for o in context.objects for sh in o.shapes])
    tube = (tube_samples(world, policed.bodies.states, sample.tube_noise)
            if policed.bodies is not None else np.zeros((0, robot.nq)))
    in_goal_tier = sample.tube_tier and context.policy != 'reachable'
    Q_path = sample.approaches if in_goal_tier else np.concatenate([sample.approaches, tube])
    w_path = (sample_weights(robot, world, Q_path, region.weight_config, THREADS)
              if len(Q_path) else np.zeros(0))
    if context.policy == 'reachable':
        samples = cover_matrix(robot, world, policed.goal_guard.samples.Q, region)
        return Objective(cover_matrix(robot, world, Q_path, region), w_path, w_path, 0,
                         len(Q_path), goal_filter(policed.goal_guard, samples))
    return goal_tiers(context, world, region, Q_path, w_path,
                      tube if in_goal_tier else np.zeros((0, robot.nq)))


def goal_tiers(context: MethodContext, world: CollisionWorld, region: SearchRegion,
               Q_path: np.ndarray, w_path: np.ndarray, Q_tube: np.ndarray) -> Objective:
    """The tiers (goal exits, goal, deep goal, passage), the one place the goal form decides
    the goal rows: under ``region`` the sample's goal configurations, each of weight 1; under
    ``joint`` the pocket (``TaskOptions.pocket_tier``) and, above it, the rays to close (the
    direct motion, the goal's exits, the routes beside the witness), a ray covered when one of
    its states is. ``Q_tube``
    (``TaskOptions.tube_tier``) joins the goal rows."""
    Q_goal = np.concatenate([context.sample.goals, Q_tube])
    exits = context.sample.exits or ExitRays(np.zeros((0, context.robot.nq)), np.zeros(0, int))
    n_goal, n_path = len(Q_goal), len(Q_path)
    R, t = placement_arrays(world, np.concatenate([Q_goal, Q_path, exits.states]))
    goal = context.policed.goal_cover
    if goal is None or goal.shape[0] != n_goal:  # the choice weighed the pocket (joint form)
        goal = cover_matrix(context.robot, world, Q_goal, region,
                            placements=(R[:n_goal], t[:n_goal]))
    deep = cover_matrix(context.robot, world, Q_goal, region, shrink=1,
                        placements=(R[:n_goal], t[:n_goal]))
    path = cover_matrix(context.robot, world, Q_path, region,
                        placements=(R[n_goal:n_goal + n_path], t[n_goal:n_goal + n_path]))
    cut = cover_matrix(context.robot, world, exits.states, region,
                       placements=(R[n_goal + n_path:], t[n_goal + n_path:]), rays=exits.ray)
    w_goal = np.ones(n_goal)
    reported = np.concatenate([np.zeros(exits.count), w_goal, np.zeros(n_goal), w_path])
    return Objective(sparse.vstack([cut, goal, deep, path], format='csr'),
                     lexicographic_weights(np.ones(exits.count), w_goal, w_goal, w_path),
                     reported, n_goal, n_path, exit_rows=exits.count)


def select_task(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig,
                context: MethodContext):
    """The method ``task``: its objective, then one greedy pass (``attack.greedy``); the picks,
    the refused picks and the step's statistics. The seed drew the sample already."""
    t0 = time.perf_counter()
    objective = task_objective(context, region)
    t1 = time.perf_counter()
    placed = greedy_pass(objective, region, budget, cfg)
    covered = placed.covered
    stats = {'task_approach_samples': objective.passage_rows,
             'task_approach_covered': int(covered[len(covered) - objective.passage_rows:].sum()),
             'task_cover_ms': round((t1 - t0) * 1e3, 1)}
    first = objective.exit_rows
    if objective.goal_rows:
        stats['task_goal_covered'] = int(covered[first:first + objective.goal_rows].sum())
    if first:
        stats.update(task_exit_rays=first, task_exits_cut=int(covered[:first].sum()))
    if len(placed.picks) < budget and placed.candidates and \
            not placed.rejected > cfg.max_rejections:
        stats['stop_reason'] = stop_reason(context, len(placed.picks), budget,
                                           region.guard is not None)
    return placed.picks, placed.rejected, stats


def stop_reason(context: MethodContext, placed: int, budget: int, guarded: bool) -> str:
    """Why fewer than ``budget`` boxes were placed although candidates were left (``guarded``:
    a goal policy's guard checked the picks)."""
    n_goal = len(context.sample.goals)
    return (f'{placed} of {budget} boxes: no further box covers a sampled task '
            'configuration' + (' within the goal policy' if guarded else '')
            + ('' if n_goal or context.goal.is_joint else
               f' (no collision-free goal configuration in '
               f'{context.sample.stats["task_goal_attempts"]} IK attempts)'))


register_method('task', select_task)

__all__ = ['Objective', 'WEIGHT_FLOOR', 'goal_filter', 'goal_tiers', 'lexicographic_weights',
           'select_task', 'stop_reason', 'task_objective', 'tube_samples']
