"""Goal configurations found before the victim's clock: the goal list of a trial, judged fairly.

A victim that takes goal configurations (MPlib, TrajOpt, ours with ``--goal-list``) can only be
charged with its path search if it was given goals. When an attack leaves only a sliver of the
goal region valid, a small sampling budget finds none, and such a trial used to count as the
victim's failure. Here the list is sampled outside every victim's clock with a generous budget:
goal configurations drawn the way the planners draw theirs (``kinematics.goal_batch``, batched)
until one is valid or ``GoalListConfig.max_attempts`` attempts are spent, then local walks
around what was found to fill K. ``attempts`` says how thin the valid goal set is. A trial whose
list stays empty is "no goal found": the task as posed fails (``psr``), the victim's path search
is not judged on it (``psr_given_goals``). Callers search the lists of their trials before the
first trial starts, so no search shares the machine with a victim's clock.

The list depends on the task and the trial's seed only, so every victim of a trial gets the
same one; lists are cached per process (``goal_list``).
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
    cap_s: float = 30.0
    """Wall-clock cap of the walks that fill the list [s] (a cut is reported as
    ``cap_hit``); the attempts are bounded by their count alone."""
    walks_per_goal: int = 20
    """Local walks (perturb a found goal by N(0, 0.3 rad), pull it back into the region) per
    missing goal once one goal is found (``goal_set``'s ratio)."""


@dataclasses.dataclass(frozen=True)
class GoalList:
    """A trial's goal configurations and what finding them took."""

    configs: np.ndarray
    """(k, nq) collision-free configurations in the goal region [rad]; k = 0: none found."""
    attempts: int
    """IK attempts made until the first valid goal (or all of them when none was found;
    walks not counted)."""
    walks: int
    """Local walks made."""
    time_s: float
    """Wall time of the search [s] (never on a victim's clock)."""
    cap_hit: bool = False
    """The search stopped at ``GoalListConfig.cap_s`` before its attempts ran out."""

    @property
    def found(self) -> bool:
        return len(self.configs) > 0

    def stats(self) -> dict:
        """The fields a trial record carries (``goal_found``, ``goal_attempts``, ...)."""
        return {'goal_found': self.found, 'goal_attempts': int(self.attempts),
                'goal_walks': int(self.walks), 'goal_search_s': float(self.time_s),
                'goal_configs': int(len(self.configs)), 'goal_cap_hit': bool(self.cap_hit)}


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
    from advocc_ros.kinematics.ik import GoalSampler

    t0 = time.monotonic()
    draw = planner_goals(robot, goal, world.collisions_batch, k, int(seed) % 2 ** 63,
                         attempts_per_sample=max(config.max_attempts // max(k, 1), 1),
                         enough=1)
    out = list(draw.Q)
    sampler = GoalSampler(robot, world.in_collision, goal,
                          np.random.default_rng([int(seed) % 2 ** 63, 1]))
    rng = np.random.default_rng([int(seed) % 2 ** 63, 2])
    deadline, walks = t0 + config.cap_s, 0
    while out and len(out) < k and walks < config.walks_per_goal * k \
            and time.monotonic() < deadline:
        walks += 1
        q = sampler.pull(out[int(rng.integers(len(out)))] + rng.normal(0.0, 0.3, robot.nq),
                         GoalSampler.walk_iterations)
        if q is not None and not world.in_collision(q):
            out.append(q)
    cap_hit = time.monotonic() >= deadline and len(out) < k
    return GoalList(np.array(out).reshape(-1, robot.nq), draw.attempts, walks,
                    time.monotonic() - t0, cap_hit)
