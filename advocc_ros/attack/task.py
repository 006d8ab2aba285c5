"""Step 1 of the attack: the task sample, the configurations the ``task`` method covers
(docs/design.md).

The paper's objective (``ours``) covers heatmap *voxel* mass, which peaks beside the shoulder,
where no plan for this task has to go. ``task`` keeps the paper's threat model (kinematics,
collision geometry and the scene; never a planner query) and its constraints C1-C3, and covers
*configurations* of this task instead, one fixed sample of them drawn here, before anything
else:

- the goal tier (``goal_tier``, the one place the goal form decides it): under the ``region``
  form the task's goal sample, drawn the way the planners' goal samplers draw theirs
  (``kinematics.goal_batch.task_goals``); what the boxes leave of it is the share of goals a
  planner can still sample;
- approaches: configurations on the final half of joint-space approaches from ``q_init`` to
  the first goal configurations (straight, and through perturbed midpoints: plans rarely run
  straight in joint space);
- the tube's perturbations: under the ``solvable`` policy the objective (``attack.objective``)
  adds configurations around the kept witness, these offsets from its states;
- under the ``joint`` form, the *direct motion* when the scene leaves it free (``direct_motion``):
  the straight joint motion from ``q_init`` to the goal, a row of the top tier, since PRM*,
  VAMP and any planner that tries the direct connection first solve the task with it.

One seeded stream draws the approaches' detours, then the tube's offsets, then the corridor
routes' offsets (``TaskOptions.corridor_routes``), so a seed gives the same sample on any
machine. ``TaskOptions`` shape it; the CLI, the heatmap server and the benchmark build them
with ``task_options``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any, Mapping

import numpy as np

from advocc_ros.attack.exits import ExitRays, rays_from
from advocc_ros.attack.types import Task
from advocc_ros.kinematics.goal_batch import TASK_GOALS, GoalDraw, goal_pocket, task_goals
from advocc_ros.limits import worker_threads
from advocc_ros.model.collision import CollisionWorld, shared_world
from advocc_ros.model.scene import SceneObject
from advocc_ros.planning.direct_motion import direct_motion_free
from advocc_ros.planning.witness import WITNESS_STEP_RAD


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
    pocket_samples: int = 256
    """Under the ``joint`` form: configurations drawn around the goal for its pocket
    (``kinematics.goal_batch.goal_pocket``; those in collision with the scene are dropped, and
    where the scene closes in on the hand that can be most of them)."""
    pocket_rad: float = 0.2
    """Standard deviation of the pocket's perturbation of the goal per joint [rad]."""
    pocket_tier: int = 0
    """Under the ``joint`` form, 1: the goal's pocket is the objective's first tier (each
    configuration weight 1, like the ``region`` form's goal sample: the boxes first close the
    pocket to the sliver the witness keeps); 0: the pocket is covered with the approaches,
    weighted by w(q)."""
    tube_tier: int = 0
    """Under the ``solvable`` policy, 1: the tube's configurations join the goal tier (each of
    weight 1, like the pocket), so the boxes narrow the witness's corridor along its length as
    they close the goal in; 0: the tube is covered with the approaches, weighted by w(q)."""
    cut_routes: int = 0
    """Under the ``solvable`` policy, 1: the witness search's other candidates (certified paths
    to the goal on the unattacked scene, the routes a planner's search finds) are rays of the
    objective's top tier, each cut when a box covers one of its states
    (``attack.exits.route_rays``), so the boxes close the routes beside the kept witness; 0:
    they are not covered."""
    corridor_routes: int = 0
    """Under the ``solvable`` policy: paths beside the kept witness drawn for the boxes to cut,
    each the witness's states shifted by one offset (N(0, ``corridor_rad``) per joint) scaled by
    sin(pi s), s from 0 at the start to 1 at the goal; those free on the scene are rays of the
    objective's top tier (``attack.exits.corridor_rays``), so a box where many of them pass
    narrows the witness's corridor there; 0: none."""
    corridor_rad: float = 0.15
    """Standard deviation of the corridor routes' offsets per joint [rad]."""
    exit_rays: int = 0
    """Under the ``joint`` form and the ``solvable`` policy, > 0: the boxes are placed for every
    candidate witness that keeps the victim margin from the scene, and the placement that
    leaves the fewest of this many RRT steps from the goal collision-free is kept
    (``attack.exits``); 0: the policy's choice alone."""
    exit_rounds: int = 0
    """With ``exit_rays``: rounds of closing the kept placement's exits, each a fresh draw of
    rays counting the latest placement; after a draw that finds exits the boxes are placed again
    with every exit found so far as the objective's tier above the goal tier, after one that
    finds none the placement is counted again; the placement with the fewest exits per draw is
    kept (``attack.exits.close_exits``); 0: none."""

    def __post_init__(self):
        for name, (valid, allowed) in OPTION_VALUES.items():
            value = getattr(self, name)
            kind = int if isinstance(getattr(TaskOptions, name), int) else numbers.Real
            if isinstance(value, bool) or not isinstance(value, kind) or not valid(value):
                raise ValueError(f'task options: {name} must be {allowed}, got {value!r}')
        approach = self.approach_goals * (1 + self.detours) * self.approach_points
        if approach > MAX_SAMPLES:
            raise ValueError(f'task options: approach_goals x (1 + detours) x approach_points '
                             f'is {approach} approach configurations; at most {MAX_SAMPLES}')


MAX_SAMPLES = 65_536
"""Most configurations one kind of the task sample may hold (the approaches, the tube, the
pocket): 16 times the data set's pocket, and a bound on the memory a request can ask for."""
MAX_EXIT_ROUNDS = 8
"""Most rounds of closing exits a request may ask for (each places the boxes once more)."""
OPTION_VALUES = {
    'approach_goals': (lambda v: 0 <= v <= TASK_GOALS, f'an integer in [0, {TASK_GOALS}]'),
    'approach_points': (lambda v: v >= 0, 'an integer >= 0'),
    'detours': (lambda v: v >= 0, 'an integer >= 0'),
    'detour_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
    'tube_samples': (lambda v: 0 <= v <= MAX_SAMPLES, f'an integer in [0, {MAX_SAMPLES}]'),
    'tube_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
    'pocket_samples': (lambda v: 0 <= v <= MAX_SAMPLES, f'an integer in [0, {MAX_SAMPLES}]'),
    'pocket_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
    'pocket_tier': (lambda v: v in (0, 1), '0 or 1'),
    'tube_tier': (lambda v: v in (0, 1), '0 or 1'),
    'cut_routes': (lambda v: v in (0, 1), '0 or 1'),
    'corridor_routes': (lambda v: 0 <= v <= MAX_SAMPLES,
                        f'an integer in [0, {MAX_SAMPLES}]'),
    'corridor_rad': (lambda v: 0 <= v < math.inf, 'a finite number >= 0'),
    'exit_rays': (lambda v: 0 <= v <= MAX_SAMPLES, f'an integer in [0, {MAX_SAMPLES}]'),
    'exit_rounds': (lambda v: 0 <= v <= MAX_EXIT_ROUNDS, f'an integer in [0, {MAX_EXIT_ROUNDS}]'),
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
"""Threads of the batched collision passes (C++): the CPUs this process may use
(``limits.worker_threads``); the flags do not depend on it."""


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


@dataclasses.dataclass(frozen=True)
class TaskSample:
    """The configurations the ``task`` method covers, before the search region is known."""

    goals: np.ndarray
    """(n, nq) the goal tier: the task's goal sample under the ``region`` form; under
    ``joint`` none (the goal is kept, never covered), or the goal's pocket with
    ``TaskOptions.pocket_tier``."""
    approaches: np.ndarray
    """(k, nq) collision-free configurations on the final half of the approaches."""
    tube_noise: np.ndarray
    """(TaskOptions.tube_samples, nq) offsets [rad] the objective adds to the kept witness's
    states under ``solvable`` (the tube)."""
    stats: dict
    """``task_goal_samples``, ``task_goal_attempts``."""
    choice: np.ndarray
    """(m, nq) what the witness choice weighs (``attack.policy.choose_witness``): the goal tier,
    or under ``joint`` the goal's pocket."""
    exits: Any = None
    """Rays for the boxes to close, the tier above the goal tier (``attack.exits.ExitRays``):
    the direct motion (``direct_motion``), then the goal's exits of ``TaskOptions.exit_rounds``
    and the routes beside the kept witness (joined for each, ``attack.api.with_rays``); or
    None."""
    tube_tier: bool = False
    """The tube's configurations are rows of the goal tier (``TaskOptions.tube_tier``), not of
    the passage."""
    corridor_noise: np.ndarray | None = None
    """(TaskOptions.corridor_routes, nq) offsets [rad] of the corridor routes beside the kept
    witness (``attack.exits.corridor_rays``), or None."""


def goal_tier(task: Task) -> GoalDraw:
    """The goal configurations of the sample, the one place the goal form decides them: under
    ``region`` the task's goal sample (``kinematics.goal_batch.task_goals``); under ``joint``
    none: the goal is its configuration, kept like the witness."""
    if task.goal.is_joint:
        return GoalDraw(np.zeros((0, task.robot.nq)), 0, 0)
    return task_goals(task.robot, task.objects, task.goal)


def direct_motion(task: Task, world: CollisionWorld) -> ExitRays | None:
    """Under the ``joint`` form, the straight motion from ``q_init`` to the goal as one ray from
    the goal, when ``world`` leaves it free (``planning.direct_motion.direct_motion_free``, the
    test of the witness search, which then plans around it: ``direct_blocker`` there);
    else None. A box that covers one of its states cuts it."""
    if not task.goal.is_joint:
        return None
    q_goal = task.goal.configuration(task.robot.joint_names)
    if not direct_motion_free(world, task.q_init, q_goal, WITNESS_STEP_RAD):
        return None
    return rays_from(q_goal, task.q_init[None])


def direct_motion_cut(task: Task, boxes: tuple[SceneObject, ...]) -> bool:
    """Whether ``boxes`` block the straight motion from ``q_init`` to the joint goal (checked
    as ``direct_motion`` checks it on the scene)."""
    world = CollisionWorld(task.robot, [sh for o in boxes for sh in o.shapes])
    return not direct_motion_free(world, task.q_init,
                                  task.goal.configuration(task.robot.joint_names),
                                  WITNESS_STEP_RAD)


def task_sample(task: Task, options: TaskOptions, seed: int) -> TaskSample:
    """The task sample (module docstring); ``seed`` draws the detours and the tube offsets.
    Under the ``joint`` form the approaches run to the goal configuration, the straight one and
    ``approach_goals x detours`` through perturbed midpoints, after the goal's pocket
    (``kinematics.goal_batch.goal_pocket``: every path ends there), which with
    ``options.pocket_tier`` is the goal tier instead; the direct motion when it is free."""
    goals = goal_tier(task)
    world = shared_world(task.robot, [sh for o in task.objects for sh in o.shapes])
    rng = np.random.default_rng(seed)
    tier = goals.Q
    if task.goal.is_joint:
        pocket = goal_pocket(task.robot, world, task.goal, options.pocket_samples,
                             options.pocket_rad)
        Q_app = approach_samples(
            world, task.q_init, task.goal.configuration(task.robot.joint_names)[None],
            options.approach_points, options.detours * max(options.approach_goals, 1),
            options.detour_rad, rng)
        if options.pocket_tier:
            tier = pocket
        else:
            Q_app = np.concatenate([pocket, Q_app])
    else:
        pocket = goals.Q
        Q_app = approach_samples(world, task.q_init, goals.Q[:options.approach_goals],
                                 options.approach_points, options.detours, options.detour_rad,
                                 rng)
    shape = (options.tube_samples, task.robot.nq)
    noise = rng.normal(0.0, options.tube_rad, shape) if options.tube_samples else np.zeros(shape)
    corridor = (rng.normal(0.0, options.corridor_rad, (options.corridor_routes, task.robot.nq))
                if options.corridor_routes else None)
    stats = {'task_goal_samples': len(tier), 'task_goal_attempts': goals.attempts}
    direct = direct_motion(task, world)
    if task.goal.is_joint:
        stats['direct_motion'] = 'free' if direct is not None else 'blocked'
    return TaskSample(tier, Q_app, noise, stats, pocket, direct, bool(options.tube_tier),
                      corridor_noise=corridor)


__all__ = ['OPTION_VALUES', 'THREADS', 'TaskOptions', 'TaskSample', 'approach_samples',
           'direct_motion', 'direct_motion_cut', 'goal_tier', 'task_options', 'task_sample']
