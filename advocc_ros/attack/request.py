"""Step 0 of the attack: the request check. A request that cannot be attacked is refused here,
with its status and a message that names what is wrong, before anything is computed or started
(the edges check it before the witness search, the core again before the steps)."""

from __future__ import annotations

import numpy as np

from advocc_ros.attack.methods import METHODS, load_method
from advocc_ros.attack.types import BOX_ID, POLICIES, AttackConfig, AttackError, AttackStatus
from advocc_ros.heatmap import Heatmap
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import SceneObject
from advocc_ros.model.task_check import TaskProblem, check_task

_TASK_STATUS = {TaskProblem.START_INVALID: AttackStatus.INVALID_START,
                TaskProblem.START_IN_COLLISION: AttackStatus.START_IN_COLLISION,
                TaskProblem.GOAL_INVALID: AttackStatus.INVALID_LINK}


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


__all__ = ['box_size', 'validate_request']
