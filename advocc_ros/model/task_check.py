"""Is a task well posed? The one check every entry point runs before a trial or an attack.

A task whose start is in collision or outside the joint limits has no solution, so a planner's
failure on it measures nothing, and an attack on it proves nothing: ``advocc evaluate``,
``advocc audit``, ``advocc attack``, ``advocc bench``, the heatmap server's ``~/attack`` and the
planner shim's ``~/plan`` refuse it with the reason (the joint and its limits, or the colliding
pair), instead of scoring "internal errors".

What is checked (cheap, exact, no planner): the start has the robot's planned joints, finite
values within the joint limits, no self collision (the SRDF-filtered pairs) and no collision
with the scene (coal on the same hulls the planners use); the goal region's link is a frame of
the robot (the region's own numbers are checked when it is built, ``GoalRegion``); a joint goal
(the ``joint`` form) is a configuration of the robot within its limits, free of self collision
and of the scene's objects: a request whose goal configuration touches the scene has no
solution. Whether a goal region can be reached is not decided here: that is what a planner's
``goal not sampled`` and an attack's ``solvable`` verdict report.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from advocc_ros.model.collision import shared_world
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.robot import RobotError, RobotModel

MAX_NAMED_PAIRS = 4
"""Colliding pairs a refusal names (the rest are counted)."""


class TaskProblem(enum.Enum):
    """Why a task is refused."""

    START_INVALID = 'start_invalid'            # wrong joints, non-finite, outside the limits
    START_IN_COLLISION = 'start_in_collision'  # self collision or collision with the scene
    GOAL_INVALID = 'goal_invalid'              # the goal region's link is not the robot's
    GOAL_IN_COLLISION = 'goal_in_collision'    # a joint goal outside the limits or colliding


@dataclasses.dataclass(frozen=True)
class TaskFault:
    """A task that cannot be planned or attacked, and why."""

    problem: TaskProblem
    message: str
    """The reason, naming the joint and its limits or the colliding pairs."""
    pairs: tuple[tuple[str, str], ...] = ()
    """Colliding pairs at the start (robot geometry, robot geometry or scene object id)."""


class InvalidTask(ValueError):
    """A task refused by :func:`check_task`; ``fault`` says why."""

    def __init__(self, fault: TaskFault):
        super().__init__(fault.message)
        self.fault = fault


def check_task(robot: RobotModel, objects, q_init, goal: GoalRegion | None) -> TaskFault | None:
    """None when the task (``objects``: the scene's ``SceneObject``s, boxes included) is well
    posed, else what is wrong with it (see the module docstring)."""
    try:
        q = robot.check_q(q_init, 'start state')
    except RobotError as exc:
        return TaskFault(TaskProblem.START_INVALID, str(exc))
    outside = np.flatnonzero((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
    if len(outside):
        return TaskFault(TaskProblem.START_INVALID, 'start state outside the joint limits: ' +
                         '; '.join(f'{robot.joint_names[i]} = {q[i]:.4g} not in '
                                   f'[{robot.lower[i]:.4g}, {robot.upper[i]:.4g}]'
                                   for i in outside))
    fault = _collision_fault(robot, tuple(objects), q)
    if fault is not None:
        return fault
    if goal is not None and not robot.model.existFrame(goal.link):
        return TaskFault(TaskProblem.GOAL_INVALID,
                         f'goal region link {goal.link!r} is not a frame of the robot')
    if goal is not None and goal.is_joint:
        return _joint_goal_fault(robot, tuple(objects), goal)
    return None


def _joint_goal_fault(robot: RobotModel, objects: tuple, goal: GoalRegion) -> TaskFault | None:
    """Why the ``joint`` goal's configuration is no goal of this task, or None."""
    try:
        q = goal.configuration(robot.joint_names)
    except SceneError as exc:
        return TaskFault(TaskProblem.GOAL_INVALID, f'joint goal: {exc}')
    outside = np.flatnonzero((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
    if len(outside):
        return TaskFault(TaskProblem.GOAL_INVALID, 'joint goal outside the joint limits: ' +
                         '; '.join(f'{robot.joint_names[i]} = {q[i]:.4g}' for i in outside))
    fault = _collision_fault(robot, objects, q, 'goal configuration')
    if fault is None:
        return None
    return TaskFault(TaskProblem.GOAL_IN_COLLISION, fault.message, fault.pairs)


def require_valid_task(robot: RobotModel, objects, q_init, goal: GoalRegion | None) -> None:
    """:func:`check_task`, raising :class:`InvalidTask` for a refused task."""
    fault = check_task(robot, objects, q_init, goal)
    if fault is not None:
        raise InvalidTask(fault)


def _collision_fault(robot: RobotModel, objects: tuple, q: np.ndarray,
                     what: str = 'start state') -> TaskFault | None:
    world = shared_world(robot, [sh for o in objects for sh in o.shapes])
    if not world.in_collision(q):
        return None
    names = [o.id if len(o.shapes) == 1 else f'{o.id}[{k}]'
             for o in objects for k in range(len(o.shapes))]
    pairs = tuple(world.colliding_pairs(q, [f'scene object {n!r}' for n in names]))
    scene = [p for p in pairs if p[1].startswith('scene object ')]
    own = [p for p in pairs if p not in scene]
    parts = [f'{a} with {b}' for a, b in (scene + own)[:MAX_NAMED_PAIRS]]
    more = len(pairs) - len(parts)
    kind = ('in collision with the scene' if scene and not own else
            'in self collision' if own and not scene else
            'in self and scene collision' if pairs else 'in collision')
    return TaskFault(TaskProblem.START_IN_COLLISION,
                     f'{what} is {kind}: ' + '; '.join(parts)
                     + (f' (and {more} more pairs)' if more > 0 else ''), pairs)


__all__ = ['InvalidTask', 'TaskFault', 'TaskProblem', 'check_task', 'require_valid_task']
