"""Goal configurations found before the victim's clock: the goal list of a trial, judged fairly.

A victim that takes goal configurations (MPlib, TrajOpt, ours with ``--goal-list``) can only be
charged with its path search if it was given goals. When an attack leaves only a sliver of the
goal region valid, a small sampling budget finds none, and such a trial used to count as the
victim's failure. Here the list is sampled outside every victim's clock with a generous budget,
by the one goal sampler (``kinematics.goal_batch.planner_goals``, the planners' attempts in
batches): until one goal is valid or ``GoalListConfig.max_attempts`` attempts are spent, then
the same sampler with the goals found as anchors (walks near them on every other attempt) to
fill K. ``attempts`` says how thin the valid goal set is. A trial whose list stays empty is "no
goal found": the task as posed fails (``psr``), the victim's path search is not judged on it
(``psr_given_goals``). Callers search the lists of their trials before the first trial starts,
so no search shares the machine with a victim's clock.

The list depends on the task and the trial's seed only (attempt budgets, never a clock), so
every victim of a trial gets the same one; lists are cached per process (``goal_list``).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from advocc_ros.model.cache import BoundedCache


@dataclasses.dataclass(frozen=True)
class GoalListConfig:
    """Budget of the search for a trial's goal list (outside the victim's clock)."""

    max_attempts: int = 50_000
    """IK attempts (random seed + damped least squares) at most before the first valid goal."""
    fill_attempts_per_goal: int = 40
    """Attempts per goal of the list once one goal is found: walks near the goals found (every
    other attempt) and random-seed IK."""


@dataclasses.dataclass(frozen=True)
class GoalList:
    """A trial's goal configurations and what finding them took."""

    configs: np.ndarray
    """(k, nq) collision-free configurations in the goal region [rad]; k = 0: none found."""
    attempts: int
    """IK attempts made until the first valid goal (or all of them when none was found)."""
    fill_attempts: int
    """Attempts made to fill the list once a goal was found."""
    time_s: float
    """Wall time of the search [s] (never on a victim's clock)."""

    @property
    def found(self) -> bool:
        return len(self.configs) > 0

    def stats(self) -> dict:
        """The fields a trial record carries (``goal_found``, ``goal_attempts``, ...)."""
        return {'goal_found': self.found, 'goal_attempts': int(self.attempts),
                'goal_fill_attempts': int(self.fill_attempts),
                'goal_search_s': float(self.time_s), 'goal_configs': int(len(self.configs))}


_CACHE: BoundedCache[GoalList] = BoundedCache('goal lists before the clock', 512)


def goal_list(robot, world, goal, k: int, seed: int, objects_key: str,
              config: GoalListConfig = GoalListConfig()) -> GoalList:
    """Up to ``k`` valid goal configurations of ``goal`` in ``world`` (our model, with the
    boxes) for the trial of ``seed``, found before any clock starts (see the module docstring);
    cached per (robot, ``objects_key`` = ``Scene.objects_hash()`` of ``world``'s scene, goal,
    k, seed, config)."""
    key = (robot.hash, objects_key, repr(goal.to_data()), int(k), int(seed), config)
    return _CACHE.get_or_make(key, lambda: search_goal_list(robot, world, goal, k, seed, config))


def search_goal_list(robot, world, goal, k: int, seed: int,
                     config: GoalListConfig = GoalListConfig()) -> GoalList:
    """:func:`goal_list` without the cache."""
    from advocc_ros.kinematics.goal_batch import planner_goals

    t0 = time.monotonic()
    seed = int(seed) % 2 ** 63
    first = planner_goals(robot, goal, world.collisions_batch, k, seed,
                          attempts_per_sample=max(config.max_attempts // max(k, 1), 1), enough=1)
    Q, filled = first.Q, 0
    if 0 < len(Q) < k:
        fill = planner_goals(robot, goal, world.collisions_batch, k, [seed, 1],
                             attempts_per_sample=config.fill_attempts_per_goal, anchors=Q)
        Q, filled = fill.Q, fill.attempts
    return GoalList(Q.reshape(-1, robot.nq), first.attempts, filled, time.monotonic() - t0)
