"""Does the attacked task still have a solution? Certificates, goal probes, the witness guard.

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

The ``solvable`` goal policy keeps the witness valid by construction: a candidate box is
refused when it comes within ``CertificateConfig.guard_margin_m`` (m) of the robot's body at any
guard state, the witness cut at ``h = CertificateConfig.guard_step_rad(L)`` (L2), L the robot's
motion bound (``RobotModel.motion_bound``). Every point of the path is within ``h / 2`` of a
guard state, where a body point has moved at most ``L h / 2 = m - 2 floor``, so every box keeps
``2 floor`` from the whole continuous sweep and the certificate (floor at every state it
measures) proves the witness again with the boxes. Candidates whose box holds a voxel centre
inside the body at a guard state are first dropped on the voxel lattice, and every pick is then
checked exactly with coal.

A task has many solutions, and the one kept decides how much of the goal set the boxes may cut:
the goal configurations whose bodies only boxes touching the witness could reach stay valid.
The witness search returns candidates, and the policy keeps the one that shields the fewest of
the task's goal samples (``choose_witness``).
"""

from __future__ import annotations

import dataclasses
import enum
import time

import numpy as np
from scipy import ndimage

from advocc_ros.attack.bodies import LinkBoxes
from advocc_ros.model.cache import BoundedCache
from advocc_ros.attack.configurations import goal_cover, touching_mask
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import THREADS, planner_goals
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject
from advocc_ros.planning.certificate import CertificateConfig
from advocc_ros.planning.witness import (WITNESS_STEP_RAD, Witness, certify,
                                         object_shape_names, witness_states)


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


class WitnessBodies:
    """The robot's body at every guard state of the witness: exact box tests and the lattice
    test of a region's candidates (built once per task and kept: ``witness_bodies``)."""

    def __init__(self, robot: RobotModel, world: CollisionWorld, witness: Witness,
                 config: CertificateConfig = CERTIFICATE):
        self.robot, self._world = robot, world
        self.step_rad = config.guard_step_rad(robot.motion_bound.max_m_per_rad)
        """Largest joint-space distance between guard states [rad] (L2)."""
        self.states = witness_states(witness.configurations(robot), self.step_rad)
        # The lattice test may use any subset of the states (it only drops boxes the exact
        # test would refuse): every k-th, about the witness search's step apart, and the last.
        k = max(int(WITNESS_STEP_RAD / self.step_rad), 1)
        self._lattice = np.unique(np.r_[np.arange(0, len(self.states), k), len(self.states) - 1])
        self._boxes: LinkBoxes | None = None

    @property
    def boxes(self) -> LinkBoxes:
        """The link hulls at every guard state (built on the first exact test: a candidate
        witness the policy does not keep never needs them)."""
        if self._boxes is None:
            self._boxes = LinkBoxes(self._world, self.states)
        return self._boxes

    def touched_by(self, center_m: np.ndarray, box_size_m: float) -> bool:
        """Whether the axis-aligned cube of edge ``box_size_m`` at ``center_m`` touches the body
        at any guard state (coal on the hulls, for the pairs whose bounding boxes meet)."""
        return self.boxes.touched_by(center_m, box_size_m)

    def touching(self, region) -> np.ndarray:
        """Mask of ``region``'s window: candidates whose box holds a voxel centre inside the
        body at a state of the lattice subset (``attack.configurations.touching_mask``, the
        relation the attack covers with). Such a box touches the body, so the exact test
        refuses it too."""
        return touching_mask(self.robot, self._world, self.states[self._lattice], region)


class WitnessGuard:
    """The ``solvable`` policy for one request: refuses boxes within ``clearance_m`` (default
    the guard margin, module docstring) of the robot at any guard state (exact, coal, on the
    cube grown by the clearance on each side, which only refuses more)."""

    reason = 'the solvable policy (the box would come too close to the witness path)'

    def __init__(self, bodies: WitnessBodies, box_size_m: float,
                 clearance_m: float = CERTIFICATE.guard_margin_m):
        self.bodies, self.box_size_m, self.clearance_m = bodies, box_size_m, clearance_m

    def admit(self, center_m: np.ndarray) -> bool:
        grown = self.box_size_m + 2 * self.clearance_m
        return not self.bodies.touched_by(center_m, grown)

    def prune(self, region, touching: np.ndarray | None = None) -> None:
        """Drop ``region``'s candidates the body touches on the lattice (``touching``: the
        bodies' mask, when the caller has it); ``admit`` still checks each pick exactly."""
        region.candidates &= ~(self.bodies.touching(region) if touching is None else touching)
        region.stats['witness_clear'] = int(region.candidates.sum())


def choose_witness(robot: RobotModel, world: CollisionWorld, region, witnesses, Q_goal
                   ) -> tuple[int, list[int], np.ndarray | None]:
    """Which of the task's candidate witnesses the ``solvable`` policy keeps: the one whose
    guard shields the fewest goal configurations of ``Q_goal`` (the task's goal sample), i.e.
    leaves the fewest that no admitted candidate box covers on the lattice, so the boxes may
    cut the most of the goal set (earlier candidates win ties). A box beside one the body
    touches counts as refused too: the exact test works on the link hulls grown by the
    clearance, which reach about a voxel beyond the lattice's solid links. (index, shielded
    count per candidate, the kept one's ``touching`` mask or None when there was no choice)."""
    if len(witnesses) == 1 or not len(Q_goal) or not region.candidates.any():
        return 0, [], None
    cover = goal_cover(robot, world, Q_goal, region).tocsc()
    cand = tuple(np.argwhere(region.candidates).T)
    shielded, masks = [], []
    for witness in witnesses:
        masks.append(witness_bodies(robot, world, witness).touching(region))
        refused = ndimage.binary_dilation(masks[-1])[cand]
        shielded.append(int((cover[:, ~refused].sum(axis=1) == 0).sum()))
    kept = int(np.argmin(shielded))
    return kept, shielded, masks[kept]


_BODIES: BoundedCache = BoundedCache('witness bodies', 8, per_task=True)
"""(robot hash, witness content hash) -> WitnessBodies."""


def witness_bodies(robot: RobotModel, world: CollisionWorld, witness: Witness
                   ) -> WitnessBodies:
    """The bodies of ``witness`` (cached per robot and path)."""
    return _BODIES.get_or_make((robot.hash, witness.content_hash()),
                               lambda: WitnessBodies(robot, world, witness))


__all__ = ['CERTIFICATE', 'GOAL_PROBE_CONVERGED', 'VERDICTS', 'Solvability', 'Verdict',
           'WitnessBodies', 'WitnessGuard', 'assess', 'certify', 'choose_witness', 'probe_goal',
           'witness_bodies', 'witness_candidates']
