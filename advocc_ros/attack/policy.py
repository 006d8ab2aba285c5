"""Step 3 of the attack: the goal policy applied to the search region; under ``solvable``, the
witness and its choice (docs/design.md).

``apply_policy`` reads ``Task.policy`` in one place and returns the region the methods choose
from, with the policy's guard (a check of each pick) and the candidates it drops:

- ``paper``: the region as it is (C3 only: boxes may block every goal pose);
- ``reachable``: the goal guard (``GoalGuard``): a pick is refused when it would leave fewer than
  ``AttackConfig.reachable_fraction`` of the task's fixed goal samples (``attack.goals``) valid;
- ``solvable``: the task keeps a solution by construction. Of the witness search's candidates
  (``planning.witness``, found at the edges), the policy keeps the one that shields the fewest of
  the task's goal samples (``choose_witness``; with a victim margin, among those that keep it
  from the scene), and refuses every box that comes within
  ``CertificateConfig.guard_margin_m`` (m) of the robot's body at any guard state of it: the
  witness cut at ``h = CertificateConfig.guard_step_rad(L)`` (L2), L the robot's motion bound.
  Every point of the path is within ``h / 2`` of a guard state, where a body point has moved at
  most ``L h / 2 = m - 2 floor``, so every box keeps ``2 floor`` from the whole continuous sweep
  and the certificate (``attack.solvable``: floor at every state it measures) proves the witness
  again with the boxes. Candidates whose box holds a voxel centre inside the body at a guard
  state are dropped on the voxel lattice first, and every pick is then checked exactly (coal).

A task has many solutions, and the one kept decides how much of the goal set the boxes may cut:
the goal configurations whose bodies only boxes touching the witness could reach stay valid.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import sparse

from advocc_ros.attack.bodies import LinkBoxes
from advocc_ros.attack.configurations import cover_matrix, touching_mask
from advocc_ros.attack.goals import GoalSamples, goal_samples
from advocc_ros.attack.region import SearchRegion
from advocc_ros.attack.solvable import CERTIFICATE
from advocc_ros.attack.types import AttackConfig, Task
from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.collision import CollisionWorld, shared_world
from advocc_ros.model.robot import RobotModel
from advocc_ros.planning.certificate import CertificateConfig
from advocc_ros.planning.witness import WITNESS_STEP_RAD, Witness, witness_states


@dataclasses.dataclass(frozen=True)
class Policed:
    """The search region under the task's goal policy, and what the policy kept."""

    region: SearchRegion
    """The candidates the policy leaves, and its guard (``region.guard``)."""
    stats: dict
    """The step's counts (``witness_clear``, ``witness_kept``, ...)."""
    goal_guard: GoalGuard | None = None
    """Under ``reachable``: the goal guard (the objective filters candidates with it too)."""
    witness: Witness | None = None
    """Under ``solvable``: the candidate witness kept."""
    bodies: WitnessBodies | None = None
    """Under ``solvable``: the robot's body along the kept witness (its guard states)."""
    goal_cover: sparse.csr_matrix | None = None
    """Under ``solvable``, when the choice computed it: the cover of the task's goal sample over
    ``region``'s candidates (the objective's goal tier, computed once)."""


def apply_policy(task: Task, region: SearchRegion, cfg: AttackConfig, witnesses: tuple,
                 Q_goal: np.ndarray | None, kept: int | None = None) -> Policed:
    """The region under ``task.policy`` (module docstring). ``witnesses``: the candidate
    witnesses (``solvable`` needs at least one); ``Q_goal``: the task's goal sample (the
    witness choice weighs the candidates on it); ``kept``: keep this candidate instead of
    choosing (``attack.exits`` tries them)."""
    if task.policy == 'reachable':
        guard = GoalGuard(goal_samples(task.robot, task.objects, task.goal), region.box_size_m,
                          cfg.reachable_fraction)
        return Policed(dataclasses.replace(region, guard=guard), {}, goal_guard=guard)
    if task.policy == 'solvable':
        scene = shared_world(task.robot, [sh for o in task.objects for sh in o.shapes])
        return keep_witness(task.robot, region, witnesses, Q_goal,
                            CERTIFICATE.guard_margin_m + cfg.victim_margin_m,
                            scene, cfg.victim_margin_m, kept)
    return Policed(region, {})


# --------------------------------------------------------------------------------------------
# reachable: the goal guard

class GoalGuard:
    """The ``reachable`` policy as a stateful check: ``admit`` commits the boxes it accepts."""

    reason = 'the goal policy (too many goal samples blocked)'

    def __init__(self, samples: GoalSamples, box_size_m: float, min_fraction: float):
        self.samples, self.box_size_m, self.min_fraction = samples, box_size_m, min_fraction
        self.valid = np.ones(len(samples.Q), dtype=bool)

    def admit(self, center_m: np.ndarray) -> bool:
        if not len(self.valid):
            return True
        left = self.valid & ~self.samples.blocked_by(center_m, self.box_size_m, among=self.valid)
        if left.mean() < self.min_fraction - 1e-12:
            return False
        self.valid = left
        return True


# --------------------------------------------------------------------------------------------
# solvable: the witness, its body and its guard

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

    def touching(self, region: SearchRegion) -> np.ndarray:
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


WITNESS_BODIES: BoundedCache = BoundedCache('witness bodies', 8, per_task=True)
"""(robot hash, witness content hash) -> WitnessBodies."""


def witness_bodies(robot: RobotModel, world: CollisionWorld, witness: Witness
                   ) -> WitnessBodies:
    """The bodies of ``witness`` (cached per robot and path)."""
    return WITNESS_BODIES.get_or_make((robot.hash, witness.content_hash()),
                                      lambda: WitnessBodies(robot, world, witness))


@dataclasses.dataclass(frozen=True)
class WitnessChoice:
    """Which candidate witness the ``solvable`` policy keeps, and what deciding it measured."""

    kept: int
    """Index of the kept candidate (earlier candidates win ties)."""
    shielded: list[int]
    """Goal samples each candidate shields (empty when there was no choice)."""
    touching: np.ndarray | None = None
    """The kept candidate's lattice mask (``WitnessBodies.touching``), when computed."""
    goal_cover: sparse.csr_matrix | None = None
    """The cover of the goal sample over the region's candidates, when computed."""
    scene_clearance_m: list[float | None] = dataclasses.field(default_factory=list)
    """Least scene clearance of each candidate measured, capped at the margin [m] (None: not
    measured; empty: no margin asked)."""


def choose_witness(robot: RobotModel, world: CollisionWorld, region: SearchRegion, witnesses,
                   Q_goal, scene: CollisionWorld | None = None, scene_margin_m: float = 0.0
                   ) -> WitnessChoice:
    """Which of the task's candidate witnesses the ``solvable`` policy keeps: the one whose
    guard shields the fewest goal configurations of ``Q_goal`` (the task's goal sample), i.e.
    leaves the fewest that no admitted candidate box covers on the lattice, so the boxes may
    cut the most of the goal set (earlier candidates win ties). A box beside one the body
    touches counts as refused too: the exact test works on the link hulls grown by the
    clearance, which reach about a voxel beyond the lattice's solid links.

    With ``scene_margin_m`` > 0 the candidates that keep that much from ``scene`` (the task's
    own objects, which the boxes' margin cannot move) come first: a victim's checker calls a
    path that grazes its scene closed (MPlib's FCL, below ~0.5 mm; docs/goal_forms.md).
    Candidates are measured in the order above until one keeps the margin; when none does, the
    one that keeps the most is kept."""
    shielded, masks, cover = [], [], None
    if len(witnesses) > 1 and Q_goal is not None and len(Q_goal) and region.candidates.any():
        cover = cover_matrix(robot, world, Q_goal, region)
        cols = cover.tocsc()
        cand = tuple(np.argwhere(region.candidates).T)
        for witness in witnesses:
            masks.append(witness_bodies(robot, world, witness).touching(region))
            refused = grown_by_a_voxel(masks[-1])[cand]
            shielded.append(int((cols[:, ~refused].sum(axis=1) == 0).sum()))
    order = list(np.argsort(shielded, kind='stable')) if shielded else list(range(len(witnesses)))
    clearance = _clear_of_scene(robot, scene, witnesses, order, scene_margin_m)
    kept = int(order[0]) if not clearance else \
        int(max(order, key=lambda i: -1.0 if clearance[i] is None else clearance[i]))
    return WitnessChoice(kept, shielded, masks[kept] if masks else None, cover, clearance)


def grown_by_a_voxel(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every voxel that shares a face with one of its voxels: the binary dilation
    by the cross (``scipy.ndimage.binary_dilation``'s default), as six shifted ORs: importing
    ``scipy.ndimage`` would cost every attacking process more than this whole step
    (docs/performance.md)."""
    grown = mask.copy()
    for axis in range(mask.ndim):
        ahead = [slice(None)] * mask.ndim
        behind = [slice(None)] * mask.ndim
        ahead[axis], behind[axis] = slice(1, None), slice(None, -1)
        grown[tuple(ahead)] |= mask[tuple(behind)]
        grown[tuple(behind)] |= mask[tuple(ahead)]
    return grown


def _clear_of_scene(robot: RobotModel, scene: CollisionWorld | None, witnesses, order,
                    margin_m: float) -> list[float | None]:
    """Least scene clearance, capped at ``margin_m``, of the candidates in ``order`` up to the
    first that keeps the margin (at the witness search's step; None: not measured). Empty when
    there is nothing to choose or no margin."""
    if len(witnesses) < 2 or not margin_m > 0 or scene is None or not scene.shapes:
        return []
    clearance = [None] * len(witnesses)
    for i in order:
        clearance[i] = scene_clearance(robot, scene, witnesses[i], margin_m)
        if clearance[i] >= margin_m:
            break
    return clearance


def scene_clearance(robot: RobotModel, scene: CollisionWorld, witness: Witness,
                    margin_m: float) -> float:
    """Least clearance of ``witness`` from ``scene``, capped at ``margin_m`` [m], at the witness
    search's step."""
    states = witness_states(witness.configurations(robot), WITNESS_STEP_RAD)
    return float(scene.scene_clearances(states, margin_m).min())


def keep_witness(robot: RobotModel, region: SearchRegion, witnesses: tuple,
                 Q_goal: np.ndarray | None, clearance_m: float = CERTIFICATE.guard_margin_m,
                 scene: CollisionWorld | None = None, scene_margin_m: float = 0.0,
                 kept: int | None = None) -> Policed:
    """The ``solvable`` policy: the kept candidate (``choose_witness``, preferring those that
    keep ``scene_margin_m`` from ``scene``, or the candidate ``kept``), its guard (boxes keep
    ``clearance_m`` from its body: the guard margin plus ``AttackConfig.victim_margin_m``),
    and the region without the candidates its body touches on the lattice."""
    world = shared_world(robot)
    choice = (WitnessChoice(kept, []) if kept is not None else
              choose_witness(robot, world, region, witnesses, Q_goal, scene, scene_margin_m))
    stats = {} if len(witnesses) == 1 else dict(
        witness_candidates=len(witnesses), witness_kept=choice.kept,
        witness_shielded=choice.shielded)
    if choice.scene_clearance_m:
        stats['witness_scene_clearance_m'] = [None if c is None else round(c, 6)
                                              for c in choice.scene_clearance_m]
    witness = witnesses[choice.kept]
    bodies = witness_bodies(robot, world, witness)
    touching = bodies.touching(region) if choice.touching is None else choice.touching
    kept = region.candidates & ~touching
    stats['witness_clear'] = int(kept.sum())
    goal_cover = (choice.goal_cover[:, kept[region.candidates]]
                  if choice.goal_cover is not None else None)
    guarded = dataclasses.replace(region, candidates=kept,
                                  guard=WitnessGuard(bodies, region.box_size_m, clearance_m))
    return Policed(guarded, stats, witness=witness, bodies=bodies, goal_cover=goal_cover)


__all__ = ['GoalGuard', 'Policed', 'WITNESS_BODIES', 'WitnessBodies', 'WitnessChoice',
           'WitnessGuard', 'apply_policy', 'choose_witness', 'keep_witness', 'scene_clearance',
           'witness_bodies']
