"""Step 3, tried through steps 4-5 (``TaskOptions.exit_rays``, ``joint`` form, ``solvable``):
the witness kept for the goal exits its boxes leave (docs/goal_forms.md).

An RRT tree rooted at a joint goal grows only by a collision-free straight step (OMPL's default
range) towards a uniform sample. While the boxes close the goal in, a planner that grows its
smaller tree (AORRTC) spends most of its samples there and gets out after about 1/p of them, p
the share of such steps that are free. The boxes may not touch the kept witness, so p is set by
where that witness leaves the goal, and no property of the witness alone predicted it on the
train split ([mbm_joint_train](../../docs/results/mbm_joint_train/README.md)). So the boxes are
placed for each candidate witness that keeps the victim margin from the scene, and the
placement whose goal leaves the fewest of ``exit_rays`` fixed steps free is kept (the policy's
own choice wins ties). Only collision checks: no planner is queried.
"""

from __future__ import annotations

from typing import Callable, TypeVar

import numpy as np

from advocc_ros.attack.policy import scene_clearance
from advocc_ros.attack.types import Task
from advocc_ros.kinematics.goal_batch import RAY_STEP_RAD, free_rays, goal_ray_ends
from advocc_ros.model.collision import CollisionWorld, shared_world
from advocc_ros.model.scene import SceneObject

Placement = TypeVar('Placement')


class GoalExits:
    """The task's goal rays (``kinematics.goal_batch.goal_ray_ends``) that are free on the
    unattacked scene, and how many of them a set of boxes leaves free."""

    def __init__(self, task: Task, rays: int):
        self.robot = task.robot
        self.q_goal = task.goal.configuration(task.robot.joint_names)
        scene = shared_world(task.robot, [sh for o in task.objects for sh in o.shapes])
        ends = goal_ray_ends(task.robot, self.q_goal, rays)
        self.ends = ends[free_rays(scene, self.q_goal, ends)]
        self.rays = rays

    def free_ends(self, boxes: tuple[SceneObject, ...]) -> np.ndarray:
        """Ends of the rays free on the scene that ``boxes`` leave free (checked at the same
        states, so they are the rays free on the scene with the boxes)."""
        if not boxes or not len(self.ends):
            return self.ends
        world = CollisionWorld(self.robot, [sh for o in boxes for sh in o.shapes])
        return self.ends[free_rays(world, self.q_goal, self.ends)]

    def left_free(self, boxes: tuple[SceneObject, ...]) -> int:
        """How many rays free on the scene ``boxes`` leave free."""
        return len(self.free_ends(boxes))

    def states(self, ends: np.ndarray) -> np.ndarray:
        """(n, nq) the states the rays to ``ends`` are checked at (the goal not included)."""
        steps = np.maximum(np.ceil(np.linalg.norm(ends - self.q_goal, axis=1) / RAY_STEP_RAD), 1)
        return np.concatenate([np.zeros((0, self.robot.nq))] + [
            self.q_goal + (np.arange(1, k + 1) / k)[:, None] * (end - self.q_goal)
            for end, k in zip(ends, steps.astype(int))])


def scene_clearances(task: Task, witnesses: tuple, margin_m: float) -> list[float] | None:
    """Each candidate witness's least clearance from the task's scene, capped at ``margin_m``
    [m]; None when there is no margin or no scene (every candidate keeps it)."""
    scene = shared_world(task.robot, [sh for o in task.objects for sh in o.shapes])
    if not margin_m > 0 or not scene.shapes:
        return None
    return [scene_clearance(task.robot, scene, w, margin_m) for w in witnesses]


def fewest_exits(task: Task, exits: GoalExits, witnesses: tuple, chosen: int,
                 first: Placement, place: Callable[[int], Placement],
                 boxes_of: Callable[[Placement], tuple[SceneObject, ...]],
                 margin_m: float) -> tuple[Placement, dict]:
    """The placement (``first``: for the policy's choice ``chosen``; ``place(k)``: for
    candidate k) whose boxes leave the goal the fewest free ``exits``, among the candidates
    that keep ``margin_m`` from the scene; and the step's statistics."""
    tried = {chosen: (first, exits.left_free(boxes_of(first)))}
    clearance = scene_clearances(task, witnesses, margin_m)
    keepers = [k for k in range(len(witnesses)) if clearance is None or clearance[k] >= margin_m]
    if chosen in keepers:
        for k in keepers:
            if k not in tried:
                placement = place(k)
                tried[k] = (placement, exits.left_free(boxes_of(placement)))
    best = min(tried, key=lambda k: (tried[k][1], k != chosen))
    stats = {'goal_exit_rays': exits.rays, 'goal_exits_unattacked': len(exits.ends),
             'witness_exits': {int(k): n for k, (_, n) in sorted(tried.items())},
             'witness_kept_for_exits': int(best), 'goal_exits': tried[best][1]}
    if clearance is not None:
        stats['witness_scene_clearance_m'] = [round(c, 6) for c in clearance]
    return tried[best][0], stats


__all__ = ['GoalExits', 'fewest_exits', 'scene_clearances']


def close_exits(exits: GoalExits, first: Placement, left: int,
                place: Callable[[np.ndarray], Placement],
                boxes_of: Callable[[Placement], tuple[SceneObject, ...]],
                rounds: int) -> tuple[Placement, dict]:
    """Up to ``rounds`` placements more for the kept witness, ``place(states)`` with the
    states along the rays left free so far joining the goal tier (a box that covers one of a
    ray's states cuts it); the placement leaving the fewest ``exits`` free (``first``, which
    leaves ``left``, on ties) and the free count of each round."""
    best, fewest = first, left
    closing = np.zeros((0, exits.robot.nq))
    counts = [left]
    free = exits.free_ends(boxes_of(first)) if rounds and left else exits.ends[:0]
    for _ in range(rounds):
        if not fewest:
            break
        closing = np.concatenate([closing, exits.states(free)])
        current = place(closing)
        free = exits.free_ends(boxes_of(current))  # counted once, closed in the next round
        counts.append(len(free))
        if counts[-1] < fewest:
            best, fewest = current, counts[-1]
    return best, {'goal_exits_by_round': counts, 'goal_exits': fewest}
