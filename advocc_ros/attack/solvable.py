"""Step 6 of the attack, the verdict: does the attacked task still have a solution, and how much
of the goal set do the boxes leave? Certificates and goal probes (docs/design.md).

A planner that fails a task with no solution has not been beaten, so every attack says which of
three things holds for its boxes (``Verdict``):

- ``certified``: the task's witness (``advocc_ros.planning.witness``) is proven a solution with
  the boxes: it starts at the task's start, the continuous path between its waypoints keeps
  every self and scene pair more than half the clearance floor apart (conservative advancement,
  ``advocc_ros.planning.certificate``) and it ends in the goal region. A solution exists.
- ``goal blocked``: among at least ``GOAL_PROBE_CONVERGED`` goal-region IK solutions from random
  seeds that converged (in ``GOAL_PROBE_MAX_ATTEMPTS`` attempts), none is collision-free.
  Strong evidence (not a proof) that no solution exists, with the counts to judge it.
- ``unknown``: neither (e.g. the witness is blocked but a free goal configuration exists).

The ``solvable`` goal policy (``attack.policy``) keeps a witness valid by construction, so its
attacks are ``certified``. ``judge`` also measures ``goal_valid_fraction`` (``attack.goals``).
"""

from __future__ import annotations

import dataclasses
import enum
import time

import numpy as np

from advocc_ros.attack.goals import goal_samples
from advocc_ros.attack.types import Task
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import THREADS, planner_goals
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject
from advocc_ros.planning.certificate import CertificateConfig
from advocc_ros.planning.witness import Witness, certify, object_shape_names


class Verdict(enum.StrEnum):
    """Whether an attacked task keeps a solution; the values are the words files carry."""

    CERTIFIED = 'certified'
    GOAL_BLOCKED = 'goal blocked'
    UNKNOWN = 'unknown'


VERDICTS = tuple(v.value for v in Verdict)
GOAL_PROBE_CONVERGED = 500
"""Converged goal IK solutions a ``goal blocked`` verdict needs, all in collision."""
GOAL_PROBE_MAX_ATTEMPTS = 5000
"""IK attempts the probe spends unless it finds a collision-free solution first."""
GOAL_PROBE_SEED = 9_100_001
CERTIFICATE = CertificateConfig()
"""The certificate's and the guard's settings (floor, guard margin)."""


@dataclasses.dataclass(frozen=True)
class Solvability:
    """Whether an attacked task keeps a solution (see the module docstring)."""

    verdict: Verdict
    message: str
    goal_probe: dict | None = None
    """``attempts``, ``converged``, ``colliding``, ``free`` of the goal probe (when it ran)."""
    witness_states: int = 0
    """States at which the continuous certificate measured distances."""
    certificate_ms: float = 0.0
    """Time the certificate took [ms]."""
    witness: Witness | None = None
    """The witness the verdict was judged with (the candidate proven, when one was)."""

    @property
    def certified(self) -> bool:
        return self.verdict == Verdict.CERTIFIED

    def to_json(self) -> dict:
        return {'verdict': self.verdict.value, 'message': self.message,
                'goal_probe': self.goal_probe, 'witness_states': self.witness_states,
                'certificate_ms': round(self.certificate_ms, 3)}


def probe_goal(robot: RobotModel, world: CollisionWorld, goal: GoalRegion,
               max_attempts: int = GOAL_PROBE_MAX_ATTEMPTS) -> dict:
    """Goal IK from random seeds (the planners' attempts, in batches:
    ``kinematics.goal_batch.planner_goals``) until a batch holds a collision-free solution or
    ``max_attempts`` are spent; the counts (``converged``: attempts that reached the region,
    ``colliding``: those in collision). Seeded and iteration-bounded: the same answer on any
    machine. A ``joint`` goal is its configuration: one attempt, free or colliding."""
    if goal.is_joint:
        free = not world.in_collision(goal.configuration(world.robot.joint_names))
        return {'attempts': 1, 'converged': 1, 'colliding': int(not free), 'free': int(free)}
    draw = planner_goals(robot, goal, lambda Q: world.collisions_batch(Q, THREADS),
                         max_attempts, GOAL_PROBE_SEED, attempts_per_sample=1, enough=1)
    free = len(draw.Q)
    return {'attempts': draw.attempts, 'converged': draw.converged,
            'colliding': draw.converged - free, 'free': int(free > 0)}


def witness_candidates(witness) -> tuple:
    """A witness argument as candidates: None -> (), a ``Witness`` -> (it,), a sequence ->
    its witnesses."""
    if witness is None:
        return ()
    return tuple(witness) if isinstance(witness, (tuple, list)) else (witness,)


def assess(robot: RobotModel, objects: tuple[SceneObject, ...], boxes: tuple[SceneObject, ...],
           goal: GoalRegion, witness, q_init: np.ndarray) -> Solvability:
    """The verdict for the task (start ``q_init``) on ``objects`` + ``boxes`` (module
    docstring); ``witness``: a ``Witness``, candidates (the first one the certificate proves
    makes the verdict ``certified``) or None."""
    everything = tuple(objects) + tuple(boxes)
    world = CollisionWorld(robot, [sh for o in everything for sh in o.shapes])
    names = object_shape_names(everything)
    t0 = time.perf_counter()
    why, states, proven = ('no witness (none was found on the unattacked scene, or none was '
                           'handed in)', 0, None)
    for candidate in witness_candidates(witness):
        why, proof = certify(robot, world, goal, candidate, q_init, CERTIFICATE, names)
        states = proof.states if proof is not None else 0
        if why is None:
            proven = candidate
            break
    ms = (time.perf_counter() - t0) * 1e3
    if why is None:
        return Solvability(Verdict.CERTIFIED, f'the witness is proven collision-free as a '
                           f'continuous path ({states} states) and ends in the goal region',
                           None, states, ms, proven)
    probe = probe_goal(robot, world, goal)
    if probe['free']:
        return Solvability(Verdict.UNKNOWN, f'{why}; a collision-free goal configuration '
                           f'exists (found after {probe["attempts"]} IK attempts)', probe,
                           states, ms)
    if probe['converged'] >= GOAL_PROBE_CONVERGED or goal.is_joint:
        return Solvability(Verdict.GOAL_BLOCKED, f'{why}; the joint goal is in collision'
                           if goal.is_joint else f'{why}; all {probe["converged"]} converged '
                           f'goal IK solutions ({probe["attempts"]} attempts) are in collision',
                           probe, states, ms)
    return Solvability(Verdict.UNKNOWN, f'{why}; the goal probe converged only '
                       f'{probe["converged"]} times in {probe["attempts"]} attempts, all in '
                       'collision', probe, states, ms)


@dataclasses.dataclass(frozen=True)
class Judgement:
    """The verdict step's answer for one attack."""

    solvable: Solvability | None
    """Whether the task keeps a solution (None: not assessed)."""
    goal_valid_fraction: float | None
    """Of the task's fixed goal samples valid without the boxes, the fraction still valid with
    them (None: the goal region has no IK solution)."""
    stats: dict
    """Its counts and times (``goal_samples``, ``goal_check_ms``, ``solvable_ms``)."""


def judge(task: Task, boxes: tuple[SceneObject, ...], box_size_m: float, witnesses: tuple,
          certify_task: bool = True) -> Judgement:
    """The verdict on ``boxes`` (the module docstring): ``goal_valid_fraction`` on the task's
    fixed goal samples (cached per task, so a task's attacks are judged on the same samples)
    and, with ``certify_task``, ``assess`` with the candidate ``witnesses``."""
    t0 = time.perf_counter()
    samples = goal_samples(task.robot, task.objects, task.goal)
    fraction = samples.valid_fraction(
        np.array([o.shapes[0].pose.position_m for o in boxes]), box_size_m)
    stats = {'goal_check_ms': round((time.perf_counter() - t0) * 1e3, 3),
             'goal_samples': len(samples.Q)}
    solvable = None
    if certify_task:
        t0 = time.perf_counter()
        solvable = assess(task.robot, task.objects, boxes, task.goal, witnesses, task.q_init)
        stats['solvable_ms'] = round((time.perf_counter() - t0) * 1e3, 3)
    return Judgement(solvable, fraction, stats)


__all__ = ['CERTIFICATE', 'GOAL_PROBE_CONVERGED', 'Judgement', 'VERDICTS', 'Solvability',
           'Verdict', 'assess', 'certify', 'judge', 'probe_goal', 'witness_candidates']
