"""The direct motion: the straight joint motion from the start to a ``joint`` goal.

Where the scene leaves it free, it solves the task: PRM*, VAMP and any planner that tries the
direct connection first take it. A witness on it would keep it free (no box may touch the
witness), so the witness search first plans around a cube on it (``direct_blocker``, used by
``planning.witness_cache.find_witnesses``), and the attack covers it as the objective's first row
(``attack.task.direct_motion``). docs/goal_forms.md, "The direct motion".
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from advocc_ros.kinematics.goal_batch import free_rays
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import SceneObject, make_box

DIRECT_BLOCK_M = 0.1
"""Edge of the cube the search plans around when the straight motion to a joint goal is free
[m] (``direct_blocker``): twice the attack's box, so that a box on the voxel grid near the
cube's centre lies inside it, clear of the witness."""
DIRECT_BLOCK_START_M = 0.1
"""Least distance of that cube from the robot at the start [m]: the attack's d_safe (C3), so a
box inside it is allowed."""
DIRECT_BLOCK_GOAL_M = 0.02
"""Least distance of that cube from the robot at the goal [m]: the goal's body is protected."""
DIRECT_BLOCK_FRACTIONS = (0.5, 0.4, 0.6, 0.3, 0.7, 0.2, 0.8)
"""Where along the straight motion the cube is tried, in this order."""


def direct_motion_free(world: CollisionWorld, q_init: np.ndarray, q_goal: np.ndarray,
                       step_rad: float) -> bool:
    """Whether the straight joint motion from ``q_init`` to ``q_goal`` is free in ``world``,
    checked every ``step_rad``: the goal ray to the start (``kinematics.goal_batch.free_rays``;
    the goal itself is the task check's)."""
    return bool(free_rays(world, q_goal, q_init[None], step_rad)[0])


def direct_blocker(robot: RobotModel, world: CollisionWorld, q_init: np.ndarray,
                   goal: GoalRegion, step_rad: float) -> SceneObject | None:
    """A cube for the search to plan around when the straight motion from ``q_init`` to a
    ``joint`` goal is free in ``world`` (checked every ``step_rad``), else None. A witness on
    that motion keeps it free (no box may touch the witness); planned around the cube, the
    witness leaves it and a box may cut it there. The cube (``DIRECT_BLOCK_M``) is centred on
    the robot at the first of ``DIRECT_BLOCK_FRACTIONS`` of the motion, and there on the first
    of its points (``_body_points``), where it keeps ``DIRECT_BLOCK_START_M`` from the robot at
    the start and ``DIRECT_BLOCK_GOAL_M`` at the goal; None when none does."""
    if not goal.is_joint:
        return None
    q_goal = goal.configuration(robot.joint_names)
    if not direct_motion_free(world, q_init, q_goal, step_rad):
        return None
    for t in DIRECT_BLOCK_FRACTIONS:
        for center in _body_points(robot, q_init + t * (q_goal - q_init), goal.link):
            cube = make_box('direct_motion_blocker', np.round(center, 9), (DIRECT_BLOCK_M,) * 3)
            near = CollisionWorld(robot, list(cube.shapes)).scene_clearances(
                np.stack([q_init, q_goal]), DIRECT_BLOCK_START_M)
            if near[0] >= DIRECT_BLOCK_START_M and near[1] >= DIRECT_BLOCK_GOAL_M:
                return cube
    return None


def _body_points(robot: RobotModel, q: np.ndarray, link: str) -> list[np.ndarray]:
    """Points on the robot at ``q`` where ``direct_blocker`` tries its cube: the origin of
    ``link`` (the hand), then the joints' origins from the last to the first (where the hand
    hardly moves, the elbow may)."""
    data = robot.create_data()
    pin.forwardKinematics(robot.model, data, q)
    return [robot.ee_pose(q, link=link).translation] + [
        data.oMi[j].translation.copy() for j in range(robot.model.njoints - 1, 0, -1)]


__all__ = ['DIRECT_BLOCK_FRACTIONS', 'DIRECT_BLOCK_GOAL_M', 'DIRECT_BLOCK_M',
           'DIRECT_BLOCK_START_M', 'direct_blocker', 'direct_motion_free']
