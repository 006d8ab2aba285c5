"""Witnesses: a collision-free joint path that proves a task has a solution.

A failure on a task with no solution says nothing about the planner, so an attack counts only
while the task keeps one. The proof is a *witness*: a joint path from ``q_init`` into the goal
region, found once on the unattacked scene by a long RRTConnect run (simplified, seeded) and then
certified against every set of boxes (``certify``): the path as a continuous motion, not a list
of states (``advocc_ros.planning.certificate``: conservative advancement with the robot's
motion bound, exact distances on the planners' hulls, a clearance floor).

The search is one loop in one planning worker (a fresh process: OMPL's RNG is seeded once per
process, so the sequence is deterministic). A task has many solutions, and which one the
``solvable`` attack must keep decides how much of the goal set its boxes may cut (the goal
configurations the witness's body shields stay valid). So the search returns *candidates*, one
per target, and the attack keeps the one that shields the fewest of the task's goal samples
(``attack.policy.choose_witness``): paths to goal configurations the planners' goal samplers
rarely land on (``rare_clear_ends``), then one into the region itself. Each run checks motions at
``WITNESS_STEP_RAD`` (discrete); a path the continuous certificate cannot prove on the unattacked
scene (it grazes an object closer than the floor between two checked states, e.g. a grasp in a
pocket a few mm wide) is dropped and the next seed tried, and when no target gave a proven path,
the targets are tried once more without simplification (shortcuts pull a path taut against the
objects). With a clearance (``AttackConfig.victim_margin_m``: room for a victim's own collision
model, whose checker calls a path that grazes its scene closed) the search plans among the
scene's primitives grown by it (``grown_objects``) and certifies on the scene itself; when that
finds nothing (a start or goal closer than that to the scene), it searches the scene as it is.
When the straight motion from the start to a ``joint`` goal is free, the search first plans
around a cube on it (``planning.direct_motion``): no box may touch the witness, so a witness on
that motion would keep it open to every planner that tries the direct connection first.

``planning.witness_cache.find_witnesses`` runs the search once per task (it chooses the scenes
the search plans among: grown by the clearance, with the direct motion's cube) and keeps its
candidates in this process and on disk, so that the next process (another ``advocc attack``, a
restarted node) skips it.

File (``<obstacles>.witness.yaml`` beside an obstacles file): ``joint_names`` (the planned
joints), ``waypoints`` (rad; the path is the linear interpolation in joint space between them),
``locked`` (every joint of the model that is not planned, at its held value) and ``source``
(how it was found).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import pathlib
import typing

import numpy as np

from advocc_ros.model.cache import CACHE_ENV
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import JOINT_TOLERANCE_RAD, GoalRegion
from advocc_ros.model.scene import Scene, SceneObject, read_yaml, save_yaml_atomic
from advocc_ros.model.shapes import Shape
from advocc_ros.model.pose import SceneError
from advocc_ros.planning.certificate import CertificateConfig, PathCertificate, certify_path
from advocc_ros.planning.types import PlanningConfig, PlanStatus

log = logging.getLogger(__name__)

WITNESS_FORMAT = 'advocc_witness'
WITNESS_STEP_RAD = 0.005
"""Joint-space step of the witness search's motion checks [rad] (half the planners' default
0.01). The certificate does not use it: it proves the continuous path."""
WITNESS_TRIES = 4
"""Seeds tried per target until one gives a path the continuous certificate proves on the
unattacked scene (a run that finds no path leaves the target)."""
END_CANDIDATES = 6
"""Rare goal configurations the search aims at before the region (``rare_clear_ends``): each
reached one is a candidate witness. A ``joint`` goal is the one end: the search makes this many
runs to it, each on seeds of its own, and each path found is a candidate."""
END_CLEARANCE_M = 2e-3
"""Least scene clearance of an aimed-at end [m]: well above the certificate's floor."""
END_TIME_S = 2.0
"""Budget of one run to an end [s] (the shipped scenes' reachable ends solve in < 0.1 s)."""
START_TOLERANCE_RAD = 1e-9
"""Largest difference [rad] between a witness's first waypoint and the task's start (and
between its locked values and the robot's)."""
WITNESS_PLANNER = 'rrtconnect'
WITNESS_SEED = 9_200_001
"""First seed of the witness search: the witness belongs to the task, not to one attack's seed,
and its random stream is not a victim's (trial k plans with seed ``seed + k``, small integers;
a victim's trial on the witness's own stream would sample the witness's end first)."""
WITNESS_TIME_S = 30.0
"""Budget of the run into the region when no rare end was reached [s] (RRTConnect solves the
shipped scenes in < 1 s); once an end was, the region run gets ``END_TIME_S``."""
WAYPOINT_DECIMALS = 12
"""Waypoints are rounded to 1e-12 rad, in memory as in files (YAML keeps them exactly)."""


@dataclasses.dataclass(frozen=True)
class Witness:
    """A joint path from the start into the goal region (see the module docstring)."""

    joint_names: tuple[str, ...]
    waypoints: np.ndarray
    """(N, nq) joint values [rad], N >= 2, in ``joint_names`` order."""
    locked: dict
    """Joint name -> value [rad or m] of every model joint that is not planned."""
    source: dict = dataclasses.field(default_factory=dict)
    """How it was found: planner, seed, time budget, path length."""

    def content_hash(self) -> str:
        """What the path is (joints, waypoints, locked values), not where it came from."""
        text = json.dumps([self.to_data()[k] for k in ('joint_names', 'waypoints', 'locked')],
                          sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def to_data(self) -> dict:
        return {'format': WITNESS_FORMAT, 'joint_names': list(self.joint_names),
                'waypoints': np.round(np.asarray(self.waypoints, float),
                                      WAYPOINT_DECIMALS).tolist(),
                'locked': {k: float(v) for k, v in self.locked.items()},
                'source': dict(self.source)}

    @classmethod
    def from_data(cls, data, where: str = 'witness') -> 'Witness':
        """A witness from a mapping; ``SceneError`` naming the field when it is malformed."""
        if not isinstance(data, dict):
            raise SceneError(f'{where}: expected a mapping with joint_names and waypoints')
        names = data.get('joint_names')
        if not isinstance(names, list) or not names or \
                not all(isinstance(n, str) for n in names):
            raise SceneError(f'{where}.joint_names: expected a list of joint names')
        try:
            waypoints = np.asarray(data.get('waypoints'), dtype=float)
        except (TypeError, ValueError):
            raise SceneError(f'{where}.waypoints: expected a list of joint vectors') from None
        if waypoints.ndim != 2 or waypoints.shape[1] != len(names) or len(waypoints) < 2:
            raise SceneError(f'{where}.waypoints: expected >= 2 rows of {len(names)} values, '
                             f'got shape {waypoints.shape}')
        if not np.all(np.isfinite(waypoints)):
            raise SceneError(f'{where}.waypoints: non-finite values')
        locked = data.get('locked') or {}
        if not isinstance(locked, dict) or not all(
                isinstance(v, (int, float)) and math.isfinite(v) for v in locked.values()):
            raise SceneError(f'{where}.locked: expected a mapping joint: finite value')
        source = data.get('source') or {}
        return cls(tuple(names), waypoints, {str(k): float(v) for k, v in locked.items()},
                   dict(source) if isinstance(source, dict) else {})

    def configurations(self, robot: RobotModel) -> np.ndarray:
        """The waypoints in ``robot``'s joint order; ``SceneError`` if the joints differ."""
        if set(self.joint_names) != set(robot.joint_names):
            raise SceneError(f'witness joints {list(self.joint_names)} are not the robot\'s '
                             f'planned joints {list(robot.joint_names)}')
        cols = [self.joint_names.index(j) for j in robot.joint_names]
        return np.asarray(self.waypoints, float)[:, cols]


def witness_states(waypoints: np.ndarray, step_rad: float = WITNESS_STEP_RAD) -> np.ndarray:
    """States at most ``step_rad`` apart (L2) along the path: each segment cut into
    ``ceil(length / step)`` equal parts (OMPL's ``validSegmentCount`` rule), endpoints included
    once. (K, nq). The ``solvable`` guard checks its boxes against the body at these states."""
    waypoints = np.asarray(waypoints, float)
    parts = [waypoints[:1]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        n = max(int(math.ceil(np.linalg.norm(b - a) / step_rad)), 1)
        t = np.arange(1, n + 1, dtype=float) / n
        parts.append(a + (b - a) * t[:, None])
    return np.concatenate(parts)


class Certified(typing.NamedTuple):
    """``certify``'s answer: ``why`` is None when the witness is proven, else the reason."""

    why: str | None
    proof: PathCertificate | None
    """The continuous check (None when an earlier check failed): states, queries, time."""

    @property
    def states(self) -> int:
        return self.proof.states if self.proof is not None else 0


def _identity_error(robot: RobotModel, witness: Witness, q_init) -> tuple[str | None, object]:
    """(why the witness is not one of this robot's from ``q_init``, its waypoints)."""
    try:
        Q = witness.configurations(robot)
    except SceneError as exc:
        return str(exc), None
    q_init = np.asarray(q_init, float)
    if q_init.shape != (robot.nq,) or not np.all(np.isfinite(q_init)):
        return f'the task\'s start must be {robot.nq} finite joint values', None
    gap = float(np.max(np.abs(Q[0] - q_init)))
    if not gap <= START_TOLERANCE_RAD:
        return (f'the witness does not start at the task\'s start state (largest joint '
                f'difference {gap:.3g} rad)'), None
    for name, value in robot.locked_values.items():
        if name not in witness.locked:
            return f'locked joint {name}: the witness does not give its value', None
        if not abs(witness.locked[name] - value) <= START_TOLERANCE_RAD:
            return (f'locked joint {name}: witness holds {witness.locked[name]}, the task '
                    f'{value}'), None
    extra = sorted(set(witness.locked) - set(robot.locked_values))
    if extra:
        return f'the witness locks joints the robot does not: {extra}', None
    return None, Q


def certify(robot: RobotModel, world: CollisionWorld, goal: GoalRegion, witness: Witness,
            q_init: np.ndarray, config: CertificateConfig = CertificateConfig(),
            shape_names: list[str] | None = None) -> Certified:
    """Whether ``witness`` is a solution of the task in ``world`` (the scene with the boxes),
    proven: its joints are the robot's planned joints, its first waypoint is ``q_init``
    (within ``START_TOLERANCE_RAD``), its locked values are the robot's, the continuous path is
    within the joint limits and free (``certify_path``: every self and scene pair keeps more
    than ``config.floor_m / 2``) and its last waypoint lies in ``goal``."""
    why, Q = _identity_error(robot, witness, q_init)
    if why is not None:
        return Certified(why, None)
    proof = certify_path(world, Q, config, shape_names)
    if not proof.proven:
        return Certified(proof.message, proof)
    if goal.is_joint:
        gap = float(np.max(np.abs(Q[-1] - goal.configuration(robot.joint_names))))
        if not gap <= JOINT_TOLERANCE_RAD:
            return Certified(f'the witness does not end at the joint goal (largest joint '
                             f'difference {gap:.3g} rad)', proof)
    elif not goal.contains(robot.ee_pose(Q[-1], link=goal.link,
                                         tool=goal.tool_offset.to_se3())):
        return Certified('the witness does not end inside the goal region', proof)
    return Certified(None, proof)


def object_shape_names(objects) -> list[str]:
    """A name for each shape of ``objects`` in world order: the object's id (``id[k]`` when
    it has several shapes), so a verdict names the object, not ``scene/k``."""
    return [o.id if len(o.shapes) == 1 else f'{o.id}[{k}]'
            for o in objects for k in range(len(o.shapes))]


def witness_file(obstacles_path: str | pathlib.Path) -> pathlib.Path:
    """``obs.yaml`` -> ``obs.witness.yaml`` (the witness written beside an obstacles file)."""
    path = pathlib.Path(obstacles_path)
    stem = path.name[:-len(path.suffix)] if path.suffix in ('.yaml', '.yml') else path.name
    return path.with_name(f'{stem}.witness.yaml')


def save_witness(path: str | pathlib.Path, witness: Witness) -> None:
    """Write a witness file atomically."""
    save_yaml_atomic(path, witness.to_data())


def load_witness(path: str | pathlib.Path) -> Witness:
    """A witness file; errors name the file and the field."""
    return Witness.from_data(read_yaml(pathlib.Path(path)), str(path))


def rare_clear_ends(robot: RobotModel, world: CollisionWorld, objects: tuple[SceneObject, ...],
                    goal: GoalRegion, k: int = END_CANDIDATES) -> np.ndarray:
    """(<= k, nq) goal configurations of the task's goal sample (``kinematics.goal_batch``)
    that the planners' goal samplers land on least often, among those at least
    ``END_CLEARANCE_M`` from the scene (a grasp pressed against its object cannot be proven),
    rarest first."""
    from advocc_ros.kinematics.goal_batch import rarest_first, task_goals

    Q = task_goals(robot, objects, goal).Q
    if not len(Q):
        return Q
    clear = Q[world.scene_clearances(Q, END_CLEARANCE_M) >= END_CLEARANCE_M] \
        if world.shapes else Q
    return clear[rarest_first(clear)[:k]]


def search_witnesses(robot: RobotModel, world: CollisionWorld,
                     objects: tuple[SceneObject, ...], q_init: np.ndarray, goal: GoalRegion,
                     time_s: float = WITNESS_TIME_S,
                     planned_among: tuple[SceneObject, ...] | None = None
                     ) -> tuple[Witness, ...]:
    """The one search (module docstring), uncached (``find_witnesses`` caches it): RRTConnect
    to each rare clear end (``END_TIME_S`` each), then into the region (``time_s``, or
    ``END_TIME_S`` once an end was reached), each target on seeds ``WITNESS_SEED``, + 1, ...
    (up to ``WITNESS_TRIES``) until the certificate proves a path; a target without a path is
    left (another seed would spend its budget too). Simplified paths first; when no target gave
    a proven path, the targets whose paths were all unproven (pulled taut against an object)
    once more without simplification. The planner sees ``planned_among`` (default ``objects``),
    the certificate ``objects``."""
    from advocc_ros.planning.worker import Planner

    targets = _targets(robot, world, objects, goal, time_s)
    names = object_shape_names(objects)
    scene = Scene(name='witness', robot=robot.spec,
                  objects=objects if planned_among is None else planned_among)
    for simplify in (True, False):
        config = PlanningConfig(time_budget_s=time_s, motion_step_rad=WITNESS_STEP_RAD,
                                stop_at_first_solution=True, simplify=simplify,
                                interpolate=False)
        found, unproven = [], []
        with Planner(scene, config) as planner:
            for q_end, budget, first_seed in targets:
                budget = END_TIME_S if found else budget
                why = _proven_path(planner, robot, world, q_init, goal, q_end, budget,
                                   simplify, names, found, first_seed)
                if why == 'unproven':
                    unproven.append((q_end, budget, first_seed))
        if found or not unproven:
            return tuple(found)
        targets = unproven
    log.warning('no witness: every path found grazed an object closer than the certificate\'s '
                'floor')
    return ()


def grown_objects(objects: tuple[SceneObject, ...], margin_m: float
                  ) -> tuple[SceneObject, ...]:
    """``objects`` with every primitive grown by ``margin_m`` on each side (a box's edges by
    ``2 margin``, a sphere's and a cylinder's radius by ``margin``, a cylinder's height by
    ``2 margin``); meshes and clouds as they are. A configuration free of the grown primitives
    keeps ``margin_m`` from the primitives themselves."""
    def grow(shape: Shape) -> Shape:
        m = margin_m
        dims = {'box': lambda d: tuple(v + 2 * m for v in d), 'sphere': lambda d: (d[0] + m,),
                'cylinder': lambda d: (d[0] + 2 * m, d[1] + m)}.get(shape.kind)
        return dataclasses.replace(shape, dims=dims(shape.dims)) if dims else shape

    return tuple(SceneObject(o.id, tuple(grow(sh) for sh in o.shapes)) for o in objects)


def _targets(robot: RobotModel, world: CollisionWorld, objects: tuple[SceneObject, ...],
             goal: GoalRegion, time_s: float) -> list[tuple]:
    """(end or None for the region, budget [s], first seed) of each run of the search: the rare
    clear ends then the region, or ``END_CANDIDATES`` runs to a ``joint`` goal, each on seeds
    of its own."""
    if goal.is_joint:
        q_goal = goal.configuration(robot.joint_names)
        return [(q_goal, time_s, WITNESS_SEED + k * WITNESS_TRIES)
                for k in range(END_CANDIDATES)]
    targets = [(end, END_TIME_S, WITNESS_SEED)
               for end in rare_clear_ends(robot, world, objects, goal)]
    return targets + [(None, time_s, WITNESS_SEED)]


def _proven_path(planner, robot: RobotModel, world: CollisionWorld, q_init: np.ndarray,
                 goal: GoalRegion, q_end: np.ndarray | None, budget: float, simplify: bool,
                 names: list[str], found: list, first_seed: int = WITNESS_SEED) -> str:
    """Seeds of one target (from ``first_seed``) until a proven path, appended to ``found``:
    'proven', 'no path' or 'unproven' (every path found failed the certificate)."""
    outcome = 'no path'
    for seed in range(first_seed, first_seed + WITNESS_TRIES):
        witness = plan_witness(planner, robot, q_init, goal, q_end, budget, seed, simplify)
        if witness is None:
            return outcome
        why = certify(robot, world, goal, witness, q_init, shape_names=names).why
        if why is None:
            found.append(witness)
            return 'proven'
        outcome = 'unproven'
        log.info('witness search (seed %d, %s): the path is not proven on the unattacked '
                 'scene: %s', seed, witness.source.get('target'), why)
    return outcome


def plan_witness(planner, robot: RobotModel, q_init: np.ndarray, goal: GoalRegion,
                 q_end: np.ndarray | None, time_s: float, seed: int, simplify: bool
                 ) -> Witness | None:
    """One RRTConnect run of ``planner`` (a ``planning.worker.Planner``) to ``q_end`` (None: to
    the region) as a witness, or None."""
    result = planner.plan(q_init, goal, WITNESS_PLANNER, time_s, seed,
                          goal_configs=None if q_end is None else q_end[None])
    if not result.success:
        level = log.error if result.status == PlanStatus.INTERNAL_ERROR else log.info
        level('witness search (seed %d): no path (%s)', seed, result.message)
        return None
    # Rounded as in its file: the witness certified is the one written and the one read back.
    waypoints = np.round(np.asarray(result.path, float), WAYPOINT_DECIMALS)
    return Witness(robot.joint_names, waypoints, dict(robot.locked_values), {
        'planner': WITNESS_PLANNER, 'seed': int(seed), 'time_budget_s': float(time_s),
        'target': ('region' if q_end is None else 'joint goal' if goal.is_joint
                   else 'rare goal configuration'),
        'simplified': simplify, 'planning_time_s': round(result.planning_time_s, 4),
        'path_length_rad': round(float(result.stats.get('path_length_rad', 0.0)), 6),
        'step_rad': WITNESS_STEP_RAD})


__all__ = ['CACHE_ENV', 'WITNESS_STEP_RAD', 'Certified', 'Witness', 'certify', 'grown_objects',
           'load_witness', 'object_shape_names', 'plan_witness', 'rare_clear_ends',
           'save_witness', 'search_witnesses', 'witness_file', 'witness_states']
