"""MotionBenchMaker requests: MoveIt ``MotionPlanRequest`` YAML files (``requestNNNN.yaml``).

What we use of a request: its ``start_state`` (every joint, fingers included: they lock the
joints outside the planning group, docs/design.md) and its first ``goal_constraints`` entry,
which is either

- a joint goal (``joint_constraints[]{joint_name, position, ...}`` covering every planned joint):
  in the ``joint`` goal form (the default) the goal is that configuration, as MoveIt, VAMP and
  MPlib plan to it; in the ``region`` form (``--goal-form region``) a goal region is built
  around its end-effector pose with tolerances the user chooses (``--goal-tol``) and carries the
  configuration as its seed (the planners offer it first), or
- a pose goal, as MoveIt writes one: ``position_constraints[0]`` (``link_name``,
  ``target_point_offset``, ``constraint_region.primitives[0]`` + ``primitive_poses[0]``) and
  ``orientation_constraints[0]`` (``orientation``, ``absolute_{x,y,z}_axis_tolerance``,
  ``parameterization``): it becomes the goal region directly. A box region oriented like the
  orientation constraint is exact (half of each box dimension is the position tolerance); any
  other region (sphere, cylinder, a box turned away) becomes the largest cube inside its
  inscribed sphere, a stricter goal, never a looser one. ``XYZ_EULER_ANGLES`` tolerances (0, the
  message default) are read as rotation-vector tolerances, which agree to first order and
  exactly for rotations about one axis; ``ROTATION_VECTOR`` (1) is exact. Without an orientation
  constraint every orientation is allowed. Joint goals in the further ``goal_constraints``
  entries (MoveIt: alternative goals; our export writes a region's seeds so) become the
  region's seeds.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import pathlib
from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.formats.mbm_fields import (WORLD_FRAMES, as_list, as_mapping, base_frame,
                                           joint_state, numbers, pose_se3, primitive_shape,
                                           virtual_joint)
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import read_yaml

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class GoalTolerance:
    """Tolerances of a goal region built around a goal configuration's end-effector pose."""

    position_m: tuple[float, float, float] = (0.02, 0.02, 0.02)
    """Half-extents of the position box in the end-effector frame [m]."""
    orientation_rad: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """Per-axis rotation-vector tolerances [rad] (MoveIt's ``absolute_*_axis_tolerance``)."""


def parse_goal_tolerance(text: str, default: GoalTolerance = GoalTolerance()) -> GoalTolerance:
    """``pos=0.02,0.02,0.02;rot=0.1,0.1,0.1``; a part left out keeps ``default``'s value, one
    number means all three axes."""
    values = dataclasses.asdict(default)
    keys = {'pos': 'position_m', 'rot': 'orientation_rad'}
    for part in filter(None, (p.strip() for p in str(text).split(';'))):
        key, sep, rest = part.partition('=')
        if not sep or key.strip() not in keys:
            raise SceneError(f'--goal-tol: expected pos=X[,Y,Z] and/or rot=R[,P,Y] separated by '
                             f'";", got {part!r}')
        try:
            nums = [float(v) for v in rest.split(',')]
        except ValueError:
            raise SceneError(f'--goal-tol {key}: expected numbers, got {rest!r}') from None
        if len(nums) == 1:
            nums *= 3
        if len(nums) != 3 or not all(np.isfinite(nums)) or min(nums) < 0:
            raise SceneError(f'--goal-tol {key}: expected 1 or 3 finite values >= 0, got {rest!r}')
        values[keys[key.strip()]] = tuple(nums)
    return GoalTolerance(**values)


@dataclasses.dataclass(frozen=True)
class MbmRequest:
    """What we use of a ``MotionPlanRequest``: the start state and a joint or a pose goal."""

    start: dict[str, float] | None
    """Every joint of ``start_state`` by name (fingers too), or ``None``."""
    goal: dict[str, float] | None
    """Joint goal: the planned joints' values by name; ``None`` for a pose goal."""
    goal_region: GoalRegion | None = None
    """Pose goal: the region the constraints describe; ``None`` for a joint goal."""


def _joint_goal(constraints: list, w: str, robot: RobotModel) -> dict[str, float]:
    names, positions = [], []
    for k, jc in enumerate(constraints):
        jc = as_mapping(jc, f'{w}.joint_constraints[{k}]')
        name = jc.get('joint_name')
        if not isinstance(name, str) or not name:
            raise SceneError(f'{w}.joint_constraints[{k}].joint_name: expected a joint name, '
                             f'got {name!r}')
        if jc.get('position') is None:
            raise SceneError(f'{w}.joint_constraints[{k}].position: missing')
        names.append(name)
        positions.append(float(numbers([jc.get('position')],
                                       f'{w}.joint_constraints[{k}].position', 'p')[0]))
    state = joint_state({'name': names, 'position': positions}, f'{w}.joint_constraints', robot)
    return {j: state[j] for j in robot.joint_names}


def _frame_transform(entry: dict, where: str, frame: str, T_base_world: pin.SE3) -> pin.SE3:
    """``T_base_frame`` of a constraint's ``header.frame_id`` (the base or the world)."""
    header = entry.get('header')
    name = '' if header is None else as_mapping(header, f'{where}.header').get('frame_id', '')
    if name in (frame, '/' + frame):
        return pin.SE3.Identity()
    if name in WORLD_FRAMES:
        return T_base_world
    raise SceneError(f'{where}.header.frame_id: {name!r} is not the robot base frame '
                     f'({frame!r}) or "world"')


def _inner_half_extents(prim: Any, where: str, R_region: np.ndarray, R_goal: np.ndarray
                        ) -> tuple[float, float, float]:
    """Half-extents of a box, in the goal orientation's frame, that lies inside the region."""
    shape = primitive_shape(prim, where, pin.SE3.Identity())
    if shape.kind == 'box' and np.allclose(R_region.T @ R_goal, np.eye(3), atol=1e-6):
        return tuple(0.5 * d for d in shape.dims)
    radius = {'box': lambda d: 0.5 * min(d), 'sphere': lambda d: d[0],
              'cylinder': lambda d: min(0.5 * d[0], d[1])}[shape.kind](shape.dims)
    log.info('%s: %s region approximated by the cube inside its inscribed sphere', where,
             shape.kind)
    return (radius / math.sqrt(3.0),) * 3


def _pose_goal(goal: dict, w: str, robot: RobotModel, T_base_world: pin.SE3) -> GoalRegion:
    """The goal region of MoveIt position + orientation constraints (see the module doc)."""
    frame = base_frame(robot)
    positions = as_list(goal.get('position_constraints'), f'{w}.position_constraints')
    orientations = as_list(goal.get('orientation_constraints'), f'{w}.orientation_constraints')
    if not positions:
        raise SceneError(f'{w}: no joint_constraints and no position_constraints (a joint or a '
                         'pose goal is needed)')
    pw = f'{w}.position_constraints[0]'
    pc = as_mapping(positions[0], pw)
    link = pc.get('link_name')
    if not isinstance(link, str) or not robot.model.existFrame(link):
        raise SceneError(f'{pw}.link_name: {link!r} is not a link of the robot')
    offset = pc.get('target_point_offset') or {'x': 0.0, 'y': 0.0, 'z': 0.0}
    offset = numbers(offset, f'{pw}.target_point_offset', 'xyz')
    region = as_mapping(pc.get('constraint_region'), f'{pw}.constraint_region')
    prims = as_list(region.get('primitives'), f'{pw}.constraint_region.primitives')
    poses = as_list(region.get('primitive_poses'), f'{pw}.constraint_region.primitive_poses')
    if not prims or len(poses) != len(prims):
        raise SceneError(f'{pw}.constraint_region: expected primitives with one primitive_pose '
                         f'each, got {len(prims)} primitives and {len(poses)} poses')
    if len(prims) > 1:
        log.warning('%s: %d region primitives; only the first is used', pw, len(prims))
    T_region = _frame_transform(pc, pw, frame, T_base_world) * pose_se3(
        poses[0], f'{pw}.constraint_region.primitive_poses[0]')
    R_goal, rot_tol = T_region.rotation, (math.pi,) * 3
    if orientations:
        ow = f'{w}.orientation_constraints[0]'
        oc = as_mapping(orientations[0], ow)
        if oc.get('link_name') != link:
            raise SceneError(f'{ow}.link_name: {oc.get("link_name")!r}, but the position '
                             f'constraint is on {link!r}')
        R_goal = (_frame_transform(oc, ow, frame, T_base_world) * pose_se3(
            {'orientation': oc.get('orientation', [0, 0, 0, 1])}, ow)).rotation
        rot_tol = tuple(float(numbers([oc.get(f'absolute_{a}_axis_tolerance', 0.0)],
                                      f'{ow}.absolute_{a}_axis_tolerance', 'v')[0])
                        for a in 'xyz')
        if min(rot_tol) < 0:
            raise SceneError(f'{ow}: axis tolerances must be >= 0, got {rot_tol}')
        rot_tol = tuple(min(t, math.pi) for t in rot_tol)
    half = _inner_half_extents(prims[0], f'{pw}.constraint_region.primitives[0]',
                               T_region.rotation, R_goal)
    try:
        return GoalRegion(center=Pose.from_se3(pin.SE3(R_goal, T_region.translation)),
                          position_tolerance_m=half, orientation_tolerance_rad=rot_tol,
                          link=link, tool_offset=Pose(tuple(offset.tolist())))
    except SceneError as exc:  # the region's own checks (a goal 1e30 m away) name no file
        raise SceneError(f'{pw}: {exc}') from None


def _seed_goals(entries: list, where: str, robot: RobotModel) -> tuple[tuple[float, ...], ...]:
    """The joint goals among further ``goal_constraints`` entries, in planned-joint order."""
    seeds = []
    for k, entry in enumerate(entries, 1):
        w = f'{where}: goal_constraints[{k}]'
        constraints = as_list(as_mapping(entry, w).get('joint_constraints'),
                              f'{w}.joint_constraints')
        if constraints:
            seeds.append(tuple(_joint_goal(constraints, w, robot).values()))
    return tuple(seeds)


def load_request(path: str | pathlib.Path, robot: RobotModel,
                 T_world_base: pin.SE3 | None = None) -> MbmRequest:
    """Start state and goal of a MotionBenchMaker ``requestNNNN.yaml``.

    The goal is the first ``goal_constraints`` entry: its ``joint_constraints`` (covering every
    planned joint; their tolerances are ignored, the goal region's replace them) or else its
    position and orientation constraints. ``T_world_base`` places the robot base in the world
    (MoveIt's ``virtual_joint``) for constraints given in the world frame; the request's own
    ``start_state.multi_dof_joint_state`` overrides it.
    """
    path = pathlib.Path(path)
    where = str(path)
    data = as_mapping(read_yaml(path), where)
    start = None
    T_world_base = T_world_base if T_world_base is not None else pin.SE3.Identity()
    if data.get('start_state') is not None:
        state = as_mapping(data['start_state'], f'{where}: start_state')
        if state.get('joint_state') is not None:
            start = joint_state(state['joint_state'], f'{where}: start_state.joint_state', robot)
        mdof = state.get('multi_dof_joint_state')
        if isinstance(mdof, dict) and mdof.get('joint_names'):
            T_world_base = virtual_joint(state, f'{where}: start_state')
    goals = as_list(data.get('goal_constraints'), f'{where}: goal_constraints')
    if not goals:
        raise SceneError(f'{where}: goal_constraints: missing or empty (a joint goal is needed)')
    w = f'{where}: goal_constraints[0]'
    goal = as_mapping(goals[0], w)
    constraints = as_list(goal.get('joint_constraints'), f'{w}.joint_constraints')
    if constraints:
        return MbmRequest(start, _joint_goal(constraints, w, robot))
    if not goal.get('position_constraints'):
        raise SceneError(f'{w}.joint_constraints: missing or empty (a joint goal, or a pose goal '
                         'as position_constraints + orientation_constraints, is needed)')
    region = _pose_goal(goal, w, robot, T_world_base.inverse())
    seeds = _seed_goals(goals[1:], where, robot)
    if seeds:
        region = dataclasses.replace(region, seed_joints=tuple(robot.joint_names), seeds=seeds)
    return MbmRequest(start, None, region)


def goal_region_at(robot: RobotModel, q_goal: dict[str, float],
                   tolerance: GoalTolerance = GoalTolerance(), form: str = 'region'
                   ) -> GoalRegion:
    """The goal of a joint goal ``q_goal`` in goal form ``form``: ``joint``, the configuration
    itself (the region's numbers only place it); ``region``, the region centred on its
    end-effector pose (forward kinematics) with ``tolerance`` and ``q_goal`` as its seed, so
    planners reach the joint goal itself, as MoveIt does, and any other configuration of the
    region as well."""
    q = robot.q_from_names(list(q_goal), list(q_goal.values()), 'goal configuration')
    return GoalRegion(center=Pose.from_se3(robot.ee_pose(q)),
                      position_tolerance_m=tuple(tolerance.position_m),
                      orientation_tolerance_rad=tuple(tolerance.orientation_rad),
                      link=robot.spec.ee_link, seed_joints=tuple(robot.joint_names),
                      seeds=(tuple(float(v) for v in q),), form=form)
