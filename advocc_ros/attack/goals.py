"""Is the goal still there? The task's fixed goal samples and exact checks of boxes against them.

Every attack reports ``goal_valid_fraction``: of a fixed-seed set of goal configurations
(drawn by the one goal sampler, ``kinematics.goal_batch.planner_goals``) that are valid without
the boxes, the fraction still valid with them (coal, exact). It tells how a planner will fail:
at 0 every goal pose is blocked (the planner reports GOAL_IN_COLLISION); above 0 the boxes must
occlude the paths.

The same samples are the ``reachable`` goal policy's (``attack.policy.GoalGuard``): a pick is
refused when it would leave fewer than ``reachable_fraction`` of them valid.

The sample set depends on the task only (robot, scene, goal region; seed fixed), so it is
computed once per task and cached: every attack of one task is judged on the same samples. It
is not the sample the ``task`` attack covers (``kinematics.goal_batch.task_goals``), so
``goal_valid_fraction`` is a held-out estimate, not the number the attack optimized.
"""

from __future__ import annotations

import numpy as np

from advocc_ros.attack.bodies import LinkBoxes
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import planner_goals
from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject, task_hash

VALIDATION_SEED = 7_345_001
"""Seed of the goal samples behind ``goal_valid_fraction`` (fixed: comparable attacks)."""
VALIDATION_SAMPLES = 32

GOAL_SAMPLES: BoundedCache = BoundedCache('goal samples', 16, per_task=True)
"""Task hash -> GoalSamples (nodes attack from several executor threads)."""


class GoalSamples:
    """A fixed set of valid goal configurations and exact box checks against their bodies."""

    def __init__(self, world: CollisionWorld, Q: np.ndarray):
        self.Q = Q
        self.bodies = LinkBoxes(world, Q)

    def blocked_by(self, center_m: np.ndarray, box_size_m: float, among=None) -> np.ndarray:
        """bool (n,): samples whose body the axis-aligned box at ``center_m`` touches (of the
        bool mask ``among`` when given; the others are False)."""
        return self.bodies.blocked_by(center_m, box_size_m, among)

    def valid_mask(self, centers_m: np.ndarray, box_size_m: float) -> np.ndarray:
        """bool (n,): the samples no box (centres (k, 3)) touches."""
        valid = np.ones(len(self.Q), dtype=bool)
        for c in np.asarray(centers_m, dtype=float).reshape(-1, 3):
            valid &= ~self.blocked_by(c, box_size_m, among=valid)
        return valid

    def valid_fraction(self, centers_m: np.ndarray, box_size_m: float) -> float | None:
        """Fraction of the samples no box touches; None without samples (no IK solution)."""
        return float(self.valid_mask(centers_m, box_size_m).mean()) if len(self.Q) else None


def goal_samples(robot: RobotModel, objects: tuple[SceneObject, ...], goal: GoalRegion,
                 n: int = VALIDATION_SAMPLES, world: CollisionWorld | None = None
                 ) -> GoalSamples:
    """The task's fixed-seed goal samples, drawn the planners' way
    (``kinematics.goal_batch.planner_goals``), cached per task (computed outside the lock: two
    threads may both compute a new task, and the first one is kept)."""
    key = task_hash(robot.hash, objects, goal, n)
    cached = GOAL_SAMPLES.get(key)
    if cached is not None:
        return cached
    world = world or CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    if goal.is_joint:  # the goal is its configuration: the one sample, when it is free
        Q = goal.configuration(robot.joint_names)[None]
        return GOAL_SAMPLES.put(key, GoalSamples(world, Q[~world.collisions_batch(Q)]))
    Q = planner_goals(robot, goal, world.collisions_batch, n, VALIDATION_SEED).Q
    return GOAL_SAMPLES.put(key, GoalSamples(world, Q))


__all__ = ['GOAL_SAMPLES', 'GoalSamples', 'VALIDATION_SAMPLES', 'goal_samples']
