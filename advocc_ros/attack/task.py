"""Method ``task``: task-conditioned coverage, the attack that makes planners fail
(docs/design.md).

The paper's objective (``ours``) covers heatmap *voxel* mass, which peaks beside the shoulder,
where no plan for this task has to go. ``task`` keeps the paper's threat model (kinematics,
collision geometry and the scene; never a planner query) and its constraints C1-C3 (the same
search region and exact coal checks), and covers *configurations* of this task instead, one
fixed sample of them, each counted once:

- goal configurations: the task's goal sample, drawn the way the planners' goal samplers draw
  theirs (``kinematics.goal_batch.task_goals``); what the boxes leave of it is the share of
  goals a planner can still sample;
- the same goal configurations reached one voxel deep into a box: among boxes that cover the
  same samples, the deeper one also blocks the unsampled goal configurations near them;
- approaches and passage: configurations on the final half of joint-space approaches from
  ``q_init`` to goal configurations (straight, and through perturbed midpoints) and, under the
  ``solvable`` policy, around the witness path (the tube), weighted by the paper's w(q).

One objective, lexicographic through its weights: a goal configuration outweighs all deep
contacts, a deep contact all approach and tube configurations. Every plan ends in the goal set,
so the boxes first cut it to the sliver the policy must leave (under ``solvable``, around the
witness's end, which the witness search places where planners rarely sample), then narrow the
passage. It is a weighted coverage, monotone and submodular, maximised by one lazy greedy pass
on a sparse cover matrix (``attack.configurations``; guarantees in docs/greedy.md), so budgets
nest: budget M's boxes are the first M of budget M + 1's. Under the ``reachable`` goal policy
(``attack.goals``) the goal set is no target: only approaches count, and candidates that would
leave too few goal samples valid are skipped.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import time
from typing import Any, Mapping

import numpy as np
from scipy import sparse

from advocc_ros.attack.configurations import cover_matrix, goal_cover, greedy_configurations
from advocc_ros.attack.goals import GoalGuard
from advocc_ros.attack.methods import MethodContext, register_method
from advocc_ros.attack.region import SearchRegion
from advocc_ros.attack.solvable import WitnessGuard
from advocc_ros.attack.types import AttackConfig
from advocc_ros.heatmap import placement_arrays, sample_weights
from advocc_ros.kinematics.goal_batch import GoalDraw, goal_pocket, task_goals
from advocc_ros.limits import worker_threads
from advocc_ros.model.collision import CollisionWorld, shared_world


@dataclasses.dataclass(frozen=True)
class TaskOptions:
    """How ``task`` samples the approach and passage configurations it covers (the goal
    configurations are the task's goal sample, ``kinematics.goal_batch.TASK_GOALS``)."""

    approach_goals: int = 64
    """Goal configurations (the first of the task's sample) the approaches run to."""
    approach_points: int = 4
    """Configurations on the final half of each approach path."""
    detours: int = 2
    """Approach paths per goal through a perturbed midpoint, besides the straight one: plans
    rarely run straight in joint space."""
    detour_rad: float = 0.4
    """Standard deviation of the midpoint perturbation per joint [rad]."""
    tube_samples: int = 256
    """Under the ``solvable`` policy: configurations drawn around the witness path and covered
    like approaches, so the boxes close the alternatives and leave a narrow passage."""
    tube_rad: float = 0.2
    """Standard deviation of the perturbation of witness states per joint [rad]."""

    def __post_init__(self):
        for name, (valid, allowed) in _OPTION_VALUES.items():
            value = getattr(self, name)
            kind = int if isinstance(getattr(TaskOptions, name), int) else numbers.Real
            if isinstance(value, bool) or not isinstance(value, kind) or not valid(value):
                raise ValueError(f'task options: {name} must be {allowed}, got {value!r}')


_OPTION_VALUES = {
    'approach_goals': (lambda v: v >= 0, 'an integer >= 0'),
    'approach_points': (lambda v: v >= 0, 'an integer >= 0'),
    'detours': (lambda v: v >= 0, 'an integer >= 0'),
    'detour_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
    'tube_samples': (lambda v: v >= 0, 'an integer >= 0'),
    'tube_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
}
"""What each :class:`TaskOptions` field accepts: (test, the words an error shows)."""


def task_options(mapping: Mapping[str, Any]) -> TaskOptions:
    """:class:`TaskOptions` with the options of ``mapping`` (option name -> value) set, the
    others at their defaults: the one way the CLI's ``--task-option``, the heatmap server's
    ``task_*`` parameters and the bench's ``task`` setting build them. An unknown name, a
    value of the wrong type or out of range is a ``ValueError`` naming the option and what
    it accepts; integers given for real-valued options become floats."""
    if not isinstance(mapping, Mapping):
        raise ValueError(f'task options: expected a mapping of option: value, got {mapping!r}')
    known = [f.name for f in dataclasses.fields(TaskOptions)]
    for name in mapping:
        if name not in known:
            raise ValueError(f'task options: unknown option {name!r}; known: '
                             f'{", ".join(known)}')
    values = dict(mapping)
    for name, value in mapping.items():
        if isinstance(getattr(TaskOptions, name), float) and isinstance(value, int) \
                and not isinstance(value, bool):
            values[name] = float(value)
    return TaskOptions(**values)


THREADS = worker_threads()
"""Threads of the batched collision passes (C++): the CPUs this process holds; the flags do not
depend on it."""


def approach_samples(world: CollisionWorld, q_init: np.ndarray, Q_goal: np.ndarray,
                     points: int, detours: int, detour_rad: float, rng: np.random.Generator
                     ) -> np.ndarray:
    """Collision-free configurations (k, nq) within the joint limits on the final half of the
    approaches to each goal (see the module docstring)."""
    nq = len(q_init)
    if not len(Q_goal) or points < 1:
        return np.zeros((0, nq))
    t = (0.5 + 0.5 * np.arange(points) / points)[None, :, None]
    starts = [np.broadcast_to(q_init, Q_goal.shape)]
    for _ in range(detours):
        mid = q_init + 0.5 * (Q_goal - q_init) + rng.normal(0.0, detour_rad, Q_goal.shape)
        starts.append(2 * mid - Q_goal)  # the path's t = 0.5 is the midpoint
    Q = np.concatenate([(q0[:, None] + t * (Q_goal - q0)[:, None]).reshape(-1, nq)
                        for q0 in starts])
    Q = Q[np.all((Q >= world.robot.lower) & (Q <= world.robot.upper), axis=1)]
    return Q[~world.collisions_batch(Q, THREADS)] if len(Q) else Q


def tube_samples(world: CollisionWorld, states: np.ndarray, n: int, sigma_rad: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Collision-free configurations (k <= n, nq) within the joint limits drawn as witness
    states (spread evenly along the path) plus N(0, ``sigma_rad``) per joint."""
    if n < 1 or not len(states):
        return np.zeros((0, world.robot.nq))
    base = states[np.linspace(0, len(states) - 1, n).round().astype(int)]
    Q = base + rng.normal(0.0, sigma_rad, base.shape)
    Q = Q[np.all((Q >= world.robot.lower) & (Q <= world.robot.upper), axis=1)]
    return Q[~world.collisions_batch(Q, THREADS)] if len(Q) else Q


WEIGHT_FLOOR = 1e-3
"""Smallest goal weight the lexicographic scaling is exact for (see
:func:`lexicographic_weights`)."""


def lexicographic_weights(w_goal: np.ndarray, w_app: np.ndarray) -> np.ndarray:
    """Weights of the three tiers (goal, deep goal, approach rows), scaled so that one goal
    configuration outweighs every deep and approach row together, and one deep row every
    approach row: the greedy then ranks candidates tier by tier. Exact when every goal weight is
    at least :data:`WEIGHT_FLOOR`; below it the scale is capped (larger factors would round the
    lower tiers out of the scores), and a tier-2 row of such a tiny weight may weigh less than
    the approaches."""
    unit = 1.0 / max(float(w_goal.min(initial=1.0)), WEIGHT_FLOOR)
    w_deep = w_goal * (1.0 + w_app.sum()) * unit
    scaled_goal = w_goal * (2.0 + w_app.sum() + w_deep.sum()) * unit
    return np.concatenate([scaled_goal, w_deep, w_app])


def _goal_filter(guard: GoalGuard, sample_cover: sparse.csr_matrix):
    """Candidates that keep enough goal samples valid by the lattice estimate (the guard's
    exact check still follows); called before every pick."""
    def feasible() -> np.ndarray:
        if not len(guard.valid):
            return np.ones(sample_cover.shape[1], dtype=bool)
        blocked = sample_cover.T @ guard.valid.astype(np.float64)  # valid samples each blocks
        left = (guard.valid.sum() - blocked) / len(guard.valid)
        return left >= guard.min_fraction - 1e-12
    return feasible


def _select_task(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig,
                 context: MethodContext):
    """The task attack: one greedy pass over the task's sampled configurations (module
    docstring); ``seed`` draws the approaches' detours and the tube."""
    opts = context.options if isinstance(context.options, TaskOptions) else TaskOptions()
    robot = context.robot
    t0 = time.perf_counter()
    world = shared_world(robot, [sh for o in context.objects for sh in o.shapes])
    rng = np.random.default_rng(seed)
    if context.goal.is_joint:
        goals, Q_goal, Q_app = _joint_rows(robot, world, context, opts, rng)
    else:
        goals = task_goals(robot, context.objects, context.goal)
        Q_goal = goals.Q
        Q_app = approach_samples(world, context.q_init, Q_goal[:opts.approach_goals],
                                 opts.approach_points, opts.detours, opts.detour_rad, rng)
    if isinstance(region.guard, WitnessGuard):
        Q_app = np.concatenate([Q_app, tube_samples(world, region.guard.bodies.states,
                                                    opts.tube_samples, opts.tube_rad, rng)])
    w_app = (sample_weights(robot, world, Q_app, region.weight_config, THREADS) if len(Q_app)
             else np.zeros(0))
    t_sample = time.perf_counter()
    cover, weights, w_report, feasible = _objective(robot, world, region, Q_goal, Q_app, w_app)
    t_cover = time.perf_counter()
    cand = np.argwhere(region.candidates)
    centers = region.center_m(cand) if len(cand) else np.zeros((0, 3))
    picks, rejected = greedy_configurations(
        cover, weights, centers, budget, region.d_min_m,
        lambda j: region.accept(cand[j]), cfg.max_rejections, feasible=feasible)
    masses, covered = _marginal_masses(cover, w_report, picks)
    n_goal = len(Q_goal)
    region.stats.update({
        'task_goal_samples': n_goal, 'task_goal_attempts': goals.attempts,
        'task_approach_samples': len(Q_app),
        'task_goal_covered': int(covered[:n_goal].sum()),
        'task_approach_covered': int(covered[cover.shape[0] - len(Q_app):].sum()),
        'task_sampling_ms': round((t_sample - t0) * 1e3, 1),
        'task_cover_ms': round((t_cover - t_sample) * 1e3, 1)})
    if len(picks) < budget and len(cand) and not rejected > cfg.max_rejections:
        region.stats['stop_reason'] = (
            f'{len(picks)} of {budget} boxes: no further box covers a sampled task '
            'configuration' + (' within the goal policy' if region.guard is not None else '')
            + ('' if n_goal or context.goal.is_joint else
               f' (no collision-free goal configuration in {goals.attempts} IK attempts)'))
    return [(cand[j], m) for j, m in zip(picks, masses)], rejected


def _joint_rows(robot, world: CollisionWorld, context: MethodContext, opts: TaskOptions,
                rng: np.random.Generator):
    """A ``joint`` goal's rows: no goal row (the goal is kept: its body and the witness are
    protected), and as path rows the goal's pocket (``goal_batch.goal_pocket``) and the
    approaches to the goal, the straight one and ``approach_goals x detours`` through
    perturbed midpoints. (draw, goal rows, path rows)."""
    q_goal = context.goal.configuration(robot.joint_names)[None]
    Q_app = approach_samples(world, context.q_init, q_goal, opts.approach_points,
                             opts.detours * max(opts.approach_goals, 1), opts.detour_rad, rng)
    Q_pocket = goal_pocket(robot, world, context.goal)
    draw = GoalDraw(np.zeros((0, robot.nq)), 0, 0)
    return draw, draw.Q, np.concatenate([Q_pocket, Q_app])


def _objective(robot, world: CollisionWorld, region: SearchRegion, Q_goal: np.ndarray,
               Q_app: np.ndarray, w_app: np.ndarray):
    """(cover matrix, greedy weights, reported weight per row, feasible filter or None): the
    three tiers of the module docstring, or under ``reachable`` the approaches alone with the
    goal filter."""
    Q = np.concatenate([Q_goal, Q_app])
    n_goal = len(Q_goal)
    R, t = placement_arrays(world, Q)
    cover = sparse.vstack([
        goal_cover(robot, world, Q_goal, region, (R[:n_goal], t[:n_goal])),
        cover_matrix(robot, world, Q_app, region, placements=(R[n_goal:], t[n_goal:]))],
        format='csr')
    w_goal = np.ones(n_goal)
    if isinstance(region.guard, GoalGuard):
        weights = np.concatenate([np.zeros(n_goal), w_app])
        feasible = _goal_filter(region.guard,
                                cover_matrix(robot, world, region.guard.samples.Q, region))
        return cover, weights, weights, feasible
    deep = cover_matrix(robot, world, Q_goal, region, shrink=1,
                        placements=(R[:n_goal], t[:n_goal]))
    cover = sparse.vstack([cover[:n_goal], deep, cover[n_goal:]], format='csr')
    weights = lexicographic_weights(w_goal, w_app)
    w_report = np.concatenate([w_goal, np.zeros(n_goal), w_app])  # each configuration once
    return cover, weights, w_report, None


def _marginal_masses(cover: sparse.csr_matrix, w: np.ndarray, picks: list[int]):
    """Each pick's newly covered weight (unscaled) and the rows covered in the end."""
    covered = np.zeros(cover.shape[0], dtype=bool)
    masses = []
    cols = cover.tocsc()
    for j in picks:
        hit = cols.indices[cols.indptr[j]:cols.indptr[j + 1]]
        newly = hit[~covered[hit]]
        masses.append(float(w[newly].sum()))
        covered[newly] = True
    return masses, covered


register_method('task', _select_task)

__all__ = ['TaskOptions', 'WEIGHT_FLOOR', 'approach_samples', 'lexicographic_weights',
           'task_options', 'tube_samples']
