"""Does the attacked task still have a solution? Certificates, goal probes, the witness guard.

A planner that fails a task with no solution has not been beaten, so every attack says which of
three things holds for its boxes:

- ``certified``: the task's witness (``advocc_ros.planning.witness``) is still valid: every
  state of every segment, cut at ``WITNESS_STEP_RAD``, is collision-free and the last one lies in
  the goal region. A solution exists; this is a proof.
- ``goal blocked``: among at least ``GOAL_PROBE_CONVERGED`` goal-region IK solutions from random
  seeds that converged, none is collision-free. Strong evidence (not a proof) that no solution
  exists, with the counts to judge it.
- ``unknown``: neither (e.g. the witness is blocked but a free goal configuration exists).

The ``solvable`` goal policy keeps the witness valid by construction: a candidate box is
refused when it comes within ``WITNESS_CLEARANCE_M`` of the robot's body at any witness state.
Between two states 0.005 rad apart a Panda link point moves at most 8.5 mm (1.70 m/rad, see
``PlanningConfig.motion_step_rad``), so that clearance keeps the boxes off the whole continuous
sweep, not only off the checked states. Candidates are first pruned on the voxel lattice (the
swept volume rasterized like the heatmap), and every pick is then checked exactly with coal.
"""

from __future__ import annotations

import collections
import dataclasses
import threading

import numpy as np

from advocc_ros.attack.coverage import box_distance
from advocc_ros.attack.goals import GoalSamples
from advocc_ros.heatmap import link_tables, placement_arrays
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import GoalSampler, IkConfig
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import SceneObject
from advocc_ros.planning.witness import Witness, certify, witness_states

VERDICTS = ('certified', 'goal blocked', 'unknown')
GOAL_PROBE_CONVERGED = 500
"""Converged goal IK solutions a ``goal blocked`` verdict needs, all in collision."""
GOAL_PROBE_MAX_ATTEMPTS = 5000
"""IK attempts the probe may spend before it answers ``unknown``."""
GOAL_PROBE_SEED = 9_100_001
WITNESS_CLEARANCE_M = 0.01
"""Distance every ``solvable`` box keeps from the robot at each witness state [m]."""


@dataclasses.dataclass(frozen=True)
class Solvability:
    """Whether an attacked task keeps a solution (see the module docstring)."""

    verdict: str
    message: str
    goal_probe: dict | None = None
    """``attempts``, ``converged``, ``colliding``, ``free`` of the goal probe (when it ran)."""
    witness_states: int = 0
    """States of the witness the certificate checked."""

    @property
    def certified(self) -> bool:
        return self.verdict == 'certified'

    def to_json(self) -> dict:
        return {'verdict': self.verdict, 'message': self.message,
                'goal_probe': self.goal_probe, 'witness_states': self.witness_states}


def probe_goal(robot: RobotModel, world: CollisionWorld, goal: GoalRegion,
               converged: int = GOAL_PROBE_CONVERGED,
               max_attempts: int = GOAL_PROBE_MAX_ATTEMPTS) -> dict:
    """Random-seed goal IK until a collision-free solution, ``converged`` colliding ones, or
    ``max_attempts``; the counts. Seeded and iteration-bounded: the same answer on any
    machine."""
    sampler = GoalSampler(robot, world.in_collision, goal,
                          np.random.default_rng(GOAL_PROBE_SEED), IkConfig())
    free = 0
    while sampler.attempts < max_attempts and sampler.converged < converged:
        if sampler.attempt() is not None:
            free = 1
            break
    return {'attempts': sampler.attempts, 'converged': sampler.converged,
            'colliding': sampler.colliding, 'free': free}


def assess(robot: RobotModel, objects: tuple[SceneObject, ...], boxes: tuple[SceneObject, ...],
           goal: GoalRegion, witness: Witness | None) -> Solvability:
    """The verdict for the task ``objects`` + ``boxes`` (see the module docstring)."""
    world = CollisionWorld(robot, [sh for o in tuple(objects) + tuple(boxes) for sh in o.shapes])
    why, states = ('no witness was found on the unattacked scene', 0) if witness is None \
        else certify(robot, world, goal, witness)
    if why is None:
        return Solvability('certified', f'the witness ({states} states) stays collision-free '
                           'and ends in the goal region', None, states)
    probe = probe_goal(robot, world, goal)
    if probe['free']:
        return Solvability('unknown', f'{why}; a collision-free goal configuration exists '
                           f'(found after {probe["attempts"]} IK attempts)', probe, states)
    if probe['converged'] >= GOAL_PROBE_CONVERGED:
        return Solvability('goal blocked', f'{why}; all {probe["converged"]} converged goal IK '
                           f'solutions ({probe["attempts"]} attempts) are in collision', probe,
                           states)
    return Solvability('unknown', f'{why}; the goal probe converged only {probe["converged"]} '
                       f'times in {probe["attempts"]} attempts, all in collision', probe, states)


class WitnessBodies:
    """The robot's body at every witness state: exact box tests and the lattice swept volume
    (built once per task and kept: ``witness_bodies``)."""

    def __init__(self, robot: RobotModel, world: CollisionWorld, witness: Witness):
        self.robot = robot
        self.states = witness_states(witness.configurations(robot))
        self.bodies = GoalSamples(world, self.states)
        self._R, self._t = placement_arrays(world, self.states)
        self._swept: dict = {}

    def swept_mask(self, grid, lo: np.ndarray, hi: np.ndarray, pitch_m: float) -> np.ndarray:
        """Voxel centres of the window ``[lo, hi)`` of ``grid`` inside the robot at some witness
        state (computed once per window)."""
        key = (grid, tuple(lo), tuple(hi), pitch_m)
        if key not in self._swept:
            origin = np.asarray(grid.origin_m) + np.asarray(lo) * grid.voxel_m
            mask = np.zeros(tuple(np.asarray(hi) - lo), dtype=bool)
            self._swept[key] = link_tables(self.robot, pitch_m).rasterize(
                mask, origin, grid.voxel_m, self._R, self._t)
        return self._swept[key]


class WitnessGuard:
    """The ``solvable`` policy for one request: refuses boxes within ``clearance_m`` of the
    robot at any witness state (exact, coal, on the cube grown by the clearance on each side,
    which only refuses more)."""

    reason = 'the solvable policy (the box would come too close to the witness path)'

    def __init__(self, bodies: WitnessBodies, box_size_m: float,
                 clearance_m: float = WITNESS_CLEARANCE_M):
        self.bodies, self.box_size_m, self.clearance_m = bodies, box_size_m, clearance_m

    def admit(self, center_m: np.ndarray) -> bool:
        grown = self.box_size_m + 2 * self.clearance_m
        return not self.bodies.bodies.touched_by(center_m, grown)

    def prune(self, region, pitch_m: float) -> None:
        """Drop ``region``'s candidates whose box comes within the clearance of the swept
        volume on the lattice; ``admit`` still checks each pick exactly."""
        if region.candidates.size:
            swept = self.bodies.swept_mask(region.grid, region.lo, region.hi, pitch_m)
            near = box_distance(swept, region.grid.voxel_m, self.box_size_m / 2,
                                self.clearance_m) < self.clearance_m
            region.candidates &= ~near
        region.stats['witness_clear'] = int(region.candidates.sum())


_BODIES: collections.OrderedDict = collections.OrderedDict()
_BODIES_LOCK = threading.Lock()


def witness_bodies(robot: RobotModel, world: CollisionWorld, witness: Witness
                   ) -> WitnessBodies:
    """The bodies of ``witness`` (cached per witness object: find_witness caches those)."""
    key = (robot.hash, id(witness))
    with _BODIES_LOCK:
        if key in _BODIES:
            _BODIES.move_to_end(key)
            return _BODIES[key][1]
    bodies = WitnessBodies(robot, world, witness)
    with _BODIES_LOCK:
        _BODIES[key] = (witness, bodies)  # keeps the witness alive, so its id stays unique
        while len(_BODIES) > 8:
            _BODIES.popitem(last=False)
    return bodies


__all__ = ['GOAL_PROBE_CONVERGED', 'VERDICTS', 'WITNESS_CLEARANCE_M', 'Solvability',
           'WitnessBodies', 'WitnessGuard', 'assess', 'certify', 'probe_goal',
           'witness_bodies']
