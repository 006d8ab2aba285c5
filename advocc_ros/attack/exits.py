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
own choice wins ties). With ``TaskOptions.exit_rounds`` the steps that placement leaves free
become the objective's top tier and the boxes are placed again (``close_exits``), each round
counted on a fresh draw, since a count on the steps the boxes were placed to close flatters
them; a placement with no exit on its draw is counted again on the next. Only collision
checks: no planner is queried.

The same tier holds the routes beside the kept witness, which the victims that get out of the
goal take (docs/goal_forms.md): the witness search's other candidates (``route_rays``) and paths
shifted from the kept witness (``corridor_rays``); a box that covers a state of one cuts it.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, TypeVar

import numpy as np

from advocc_ros.attack.policy import scene_clearance
from advocc_ros.attack.types import Task
from advocc_ros.kinematics.goal_batch import RAY_STEP_RAD, THREADS, free_rays, goal_ray_ends
from advocc_ros.model.collision import CollisionWorld, shared_world
from advocc_ros.model.scene import SceneObject
from advocc_ros.planning.witness import witness_states

Placement = TypeVar('Placement')


@dataclasses.dataclass(frozen=True)
class ExitRays:
    """Goal rays for the boxes to close (``close_exits``): the states each ray is checked at
    and the ray each state belongs to. A box that covers one state of a ray cuts it, so the
    objective counts a ray once, covered when any of its states is
    (``cover_matrix(..., rays=ray)``)."""

    states: np.ndarray
    """(n, nq) the rays' states, the goal not included."""
    ray: np.ndarray
    """(n,) int: the ray of each state, numbered 0, 1, ... in order."""

    @property
    def count(self) -> int:
        return int(self.ray[-1]) + 1 if len(self.ray) else 0

    def join(self, more: 'ExitRays') -> 'ExitRays':
        """These rays and ``more``, renumbered after them."""
        return ExitRays(np.concatenate([self.states, more.states]),
                        np.concatenate([self.ray, more.ray + self.count]))


class GoalExits:
    """The task's goal rays (``kinematics.goal_batch.goal_ray_ends``) that are free on the
    unattacked scene, and how many of them a set of boxes leaves free: draw 0 fixed (the
    candidates' counts), a fresh draw for each round of ``close_exits`` (a count on the rays
    the boxes were placed to close would flatter them)."""

    def __init__(self, task: Task, rays: int):
        self.robot = task.robot
        self.q_goal = task.goal.configuration(task.robot.joint_names)
        self.scene = shared_world(task.robot, [sh for o in task.objects for sh in o.shapes])
        ends = goal_ray_ends(task.robot, self.q_goal, rays)
        self.ends = ends[free_rays(self.scene, self.q_goal, ends)]
        self.rays = rays

    def free_ends(self, boxes: tuple[SceneObject, ...], draw: int = 0) -> np.ndarray:
        """Ends of the rays of ``draw`` free on the scene with ``boxes`` (draw 0: of those
        free on the scene, checked at the same states; a later draw: the boxes checked first,
        they end most rays within a few steps, then the scene on the rest)."""
        world = CollisionWorld(self.robot, [sh for o in boxes for sh in o.shapes])
        if not draw:
            return self.ends[free_rays(world, self.q_goal, self.ends)] if boxes else self.ends
        ends = goal_ray_ends(self.robot, self.q_goal, self.rays, draw)
        ends = ends[free_rays(world, self.q_goal, ends)] if boxes else ends
        return ends[free_rays(self.scene, self.q_goal, ends)]

    def left_free(self, boxes: tuple[SceneObject, ...], draw: int = 0) -> int:
        """How many rays of ``draw`` free on the scene ``boxes`` leave free."""
        return len(self.free_ends(boxes, draw))

    def rays_to(self, ends: np.ndarray) -> ExitRays:
        """The rays to ``ends`` and the states they are checked at."""
        return rays_from(self.q_goal, ends)


def rays_from(q_goal: np.ndarray, ends: np.ndarray) -> ExitRays:
    """The straight motions from ``q_goal`` to the rows of ``ends`` as rays, each checked every
    ``RAY_STEP_RAD`` (its end included, the goal not)."""
    steps = np.maximum(np.ceil(np.linalg.norm(ends - q_goal, axis=1) / RAY_STEP_RAD),
                       1).astype(int)
    states = np.concatenate([np.zeros((0, len(q_goal)))] + [
        q_goal + (np.arange(1, k + 1) / k)[:, None] * (end - q_goal)
        for end, k in zip(ends, steps)])
    return ExitRays(states, np.repeat(np.arange(len(ends)), steps))


def route_rays(robot, witnesses: tuple, kept) -> ExitRays | None:
    """The candidate witnesses other than ``kept`` (the routes planners found on the
    unattacked scene besides the kept one) as rays, each checked every ``RAY_STEP_RAD``, its
    start and goal not (no box may touch them); None when there is no other. A victim's
    solutions on an attacked problem run along these routes (docs/goal_forms.md), and a box
    that covers one state of a route cuts it."""
    kept_hash = None if kept is None else kept.content_hash()
    states = [witness_states(w.configurations(robot), RAY_STEP_RAD)[1:-1] for w in witnesses
              if w.content_hash() != kept_hash]
    states = [s for s in states if len(s)]
    if not states:
        return None
    return ExitRays(np.concatenate(states), np.repeat(np.arange(len(states)),
                                                      [len(s) for s in states]))


def corridor_rays(scene: CollisionWorld, waypoints: np.ndarray, offsets: np.ndarray
                  ) -> ExitRays | None:
    """Paths beside the witness ``waypoints``: its states every ``RAY_STEP_RAD`` shifted by
    each row of ``offsets`` times sin(pi s) (s the share of its length, 0 at the start and 1 at
    the goal, so every path joins the start and the goal), as rays of their inner states; only
    those within the joint limits and free on ``scene`` (the others are no way through); None
    when none is. A box that covers a state of many narrows the corridor where they pass."""
    states = witness_states(waypoints, RAY_STEP_RAD)
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(states, axis=0), axis=1))]
    bump = np.sin(np.pi * along / max(along[-1], 1e-12))[1:-1]
    paths = states[None, 1:-1] + offsets[:, None, :] * bump[None, :, None]
    robot = scene.robot
    ok = np.all((paths >= robot.lower) & (paths <= robot.upper), axis=(1, 2))
    flat = paths[ok].reshape(-1, robot.nq)
    if len(flat):
        ok[ok] = ~scene.collisions_batch(flat, THREADS).reshape(int(ok.sum()), -1).any(axis=1)
    if not ok.any():
        return None
    return ExitRays(paths[ok].reshape(-1, robot.nq),
                    np.repeat(np.arange(int(ok.sum())), paths.shape[1]))


def rays_cut(robot, rays: ExitRays | None, boxes: tuple[SceneObject, ...]) -> int:
    """How many of ``rays`` the boxes block (the robot collides with a box at one of the
    states the ray is checked at)."""
    if rays is None or not rays.count:
        return 0
    world = CollisionWorld(robot, [sh for o in boxes for sh in o.shapes])
    hit = world.collisions_batch(rays.states, THREADS) if boxes else np.zeros(len(rays.ray), bool)
    return int(np.unique(rays.ray[hit]).size)


ESCAPE_DRAW = 1_000
"""The draw of rays the escape share is measured on (``escape_share``): none of those the
attack counts and closes (0 to ``attack.task.MAX_EXIT_ROUNDS``)."""


def escape_share(robot, shapes: list, q_goal: np.ndarray, rays: int, step_rad: float) -> dict:
    """How many of ``rays`` RRT steps from the joint goal ``q_goal`` (draw :data:`ESCAPE_DRAW`,
    independent of the attack's) are free on ``shapes`` checked every ``step_rad`` (a victim's
    step): p = free / rays. A tree rooted at the goal leaves it after about 1/p steps (AORRTC's
    PSR in 5 s about 1 - exp(-25,000 p), docs/goal_forms.md)."""
    ends = goal_ray_ends(robot, q_goal, rays, ESCAPE_DRAW)
    free = free_rays(CollisionWorld(robot, list(shapes)), q_goal, ends, step_rad)
    return {'rays': int(rays), 'free': int(free.sum()), 'step_rad': float(step_rad)}


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
                 margin_m: float) -> tuple[Placement, np.ndarray, dict]:
    """The placement (``first``: for the policy's choice ``chosen``; ``place(k)``: for
    candidate k) whose boxes leave the goal the fewest free ``exits``, among the candidates
    that keep ``margin_m`` from the scene; the ends of the rays it leaves free (draw 0); and
    the step's statistics."""
    tried = {chosen: (first, exits.free_ends(boxes_of(first)))}
    clearance = scene_clearances(task, witnesses, margin_m)
    keepers = [k for k in range(len(witnesses)) if clearance is None or clearance[k] >= margin_m]
    if chosen in keepers:
        for k in keepers:
            if k not in tried:
                placement = place(k)
                tried[k] = (placement, exits.free_ends(boxes_of(placement)))
    best = min(tried, key=lambda k: (len(tried[k][1]), k != chosen))
    stats = {'goal_exit_rays': exits.rays, 'goal_exits_unattacked': len(exits.ends),
             'witness_exits': {int(k): len(free) for k, (_, free) in sorted(tried.items())},
             'witness_kept_for_exits': int(best), 'goal_exits': len(tried[best][1])}
    if clearance is not None:
        stats['witness_scene_clearance_m'] = [round(c, 6) for c in clearance]
    return tried[best][0], tried[best][1], stats


def close_exits(exits: GoalExits, first: Placement, free: np.ndarray,
                place: Callable[[ExitRays], Placement],
                boxes_of: Callable[[Placement], tuple[SceneObject, ...]],
                rounds: int) -> tuple[Placement, dict]:
    """Up to ``rounds`` fresh draws of rays (round r: ``draw`` r), each counting the latest
    placement for the kept witness. After a draw that finds exits the boxes are placed again,
    ``place(rays)`` with every exit found so far to close (the objective's exit tier, above the
    goal tier), and the new placement is counted on the next draw; after a draw that finds none
    the same placement is counted again (no exit in one draw is not p = 0). The placement with
    the fewest exits per draw it was counted on (``first``, which leaves the rays to ``free``
    of draw 0, on ties), and the counts."""
    placed, found = [first], [[len(free)]]  # per placement: its exits on each draw counted
    closing = exits.rays_to(free)
    for draw in range(1, rounds + 1):
        if len(free):
            placed.append(place(closing))
            found.append([])
        free = exits.free_ends(boxes_of(placed[-1]), draw)
        closing = closing.join(exits.rays_to(free))
        found[-1].append(len(free))
    kept = min(range(len(placed)), key=lambda i: (sum(found[i]) / len(found[i]), i))
    first_draw = sum(len(f) for f in found[:kept])
    return placed[kept], {'goal_exits_by_round': [n for f in found for n in f],
                          'goal_exits': sum(found[kept]),
                          'goal_exit_draws_kept': list(range(first_draw,
                                                             first_draw + len(found[kept])))}


__all__ = ['ESCAPE_DRAW', 'ExitRays', 'GoalExits', 'close_exits', 'escape_share', 'fewest_exits',
           'corridor_rays', 'rays_cut', 'rays_from', 'route_rays', 'scene_clearances']
