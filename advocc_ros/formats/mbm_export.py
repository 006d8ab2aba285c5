"""Export of a task as a MotionBenchMaker problem: MoveIt ``PlanningScene``, ``MotionPlanRequest``
and ``RobotTrajectory`` messages serialised to YAML, in the ROS-message layout the importer
(``mbm``, ``mbm_request``) reads back.

- scene (``sceneNNNN.yaml``): ``world.collision_objects[]`` (primitives with shape_msgs type
  values, cylinders ``[height, radius]``; inline meshes), each with ``header.frame_id: world``,
  and a ``robot_state`` of every joint (the locked fingers too) with MoveIt's ``virtual_joint``
  at identity: the robot base is the world;
- request (``requestNNNN.yaml``): the start state and exactly the task's goal. A ``joint`` goal is
  ``goal_constraints[0].joint_constraints``, the configuration itself (as MotionBenchMaker writes
  it). A goal region is ``goal_constraints[0]``: a position constraint whose region is one box of
  the region's full extents posed at its centre (``target_point_offset`` = the tool point) and an
  orientation constraint with the centre's orientation and the region's per-axis tolerances in
  ``ROTATION_VECTOR`` parameterization. Both are exactly our region (MoveIt measures the rotation
  error as the rotation vector of ``R_goal^T R_link``, as we do). The region's seeds (a joint goal
  it was built around) that the scene leaves free follow as joint goals in
  ``goal_constraints[1:]``: for MoveIt an alternative goal inside the region, for our importer the
  region's seeds; a seed the attack's boxes block is left out (it is no goal there);
- trajectory (``trajectoryNNNN.yaml``): the witness path's waypoints as
  ``joint_trajectory.points[]`` (linear interpolation in joint space between them is the
  path), timed at the joints' velocity limits (each segment takes as long as its slowest joint
  needs at full speed; no acceleration limits).
Only the robot the importer assumes (the default Panda, fingers at any value) can be exported:
the MotionBenchMaker files do not name a robot model, MoveIt's configuration does.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import Sequence

import numpy as np

from advocc_ros.model.goal import GoalRegion
from advocc_ros.formats.mbm_fields import as_list, as_mapping, base_frame, floats
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.robot import RobotModel, RobotSpec
from advocc_ros.model.scene import Scene, SceneObject, read_yaml, save_yaml_atomic

PRIMITIVE_TYPES = {'box': 1, 'sphere': 2, 'cylinder': 3}
"""shape_msgs/SolidPrimitive type values."""
ROTATION_VECTOR = 1
"""moveit_msgs/OrientationConstraint.ROTATION_VECTOR."""
JOINT_GOAL_TOLERANCE_RAD = 1e-3
"""Tolerance of the joint goal written for a region seed [rad]: the seed is a point goal."""


@dataclasses.dataclass(frozen=True)
class ProblemFiles:
    """The three files of one exported problem."""

    scene: pathlib.Path
    request: pathlib.Path
    trajectory: pathlib.Path


def problem_files(out_dir: str | pathlib.Path, index: int) -> ProblemFiles:
    """``sceneNNNN.yaml``, ``requestNNNN.yaml``, ``trajectoryNNNN.yaml`` in ``out_dir``."""
    out = pathlib.Path(out_dir)
    return ProblemFiles(out / f'scene{index:04d}.yaml', out / f'request{index:04d}.yaml',
                        out / f'trajectory{index:04d}.yaml')


def check_exportable(scene: Scene) -> None:
    """Refuse what the files cannot carry: another robot model, clouds, a rotated tool."""
    if dataclasses.replace(scene.robot, locked=()) != RobotSpec():
        raise SceneError(f'{scene.name}: only the default Panda can be exported as a '
                         'MotionBenchMaker problem (the files do not name a robot model)')
    if scene.start is None or scene.goal is None:
        raise SceneError(f'{scene.name}: a start and a goal region are needed to export')
    if not np.allclose(scene.goal.tool_offset.to_se3().rotation, np.eye(3), atol=1e-9):
        raise SceneError(f'{scene.name}: goal.tool_offset has a rotation; MoveIt\'s '
                         'target_point_offset is a point, so the region cannot be written')
    clouds = [o.id for o in scene.objects if any(s.kind == 'cloud' for s in o.shapes)]
    if clouds:
        raise SceneError(f'{scene.name}: point-cloud objects {clouds} cannot be exported as '
                         'collision objects')


def _header(frame: str = 'world') -> dict:
    return {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': frame}


def _xyz(v) -> dict:
    return {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])}


def _quat(q) -> dict:
    return {'x': float(q[0]), 'y': float(q[1]), 'z': float(q[2]), 'w': float(q[3])}


def pose_data(pose: Pose) -> dict:
    """A ``geometry_msgs/Pose`` mapping."""
    return {'position': _xyz(pose.position_m), 'orientation': _quat(pose.quat_xyzw)}


def robot_state_data(joints: dict[str, float]) -> dict:
    """A ``moveit_msgs/RobotState`` of ``joints`` with the ``virtual_joint`` at identity."""
    return {'joint_state': {'header': _header(), 'name': list(joints),
                            'position': [float(v) for v in joints.values()],
                            'velocity': [], 'effort': []},
            'multi_dof_joint_state': {
                'header': _header(), 'joint_names': ['virtual_joint'],
                'transforms': [{'translation': _xyz((0, 0, 0)),
                                'rotation': _quat((0, 0, 0, 1))}],
                'twist': [], 'wrench': []},
            'attached_collision_objects': [], 'is_diff': False}


def collision_object_data(obj: SceneObject) -> dict:
    """A ``moveit_msgs/CollisionObject`` (ADD) of ``obj``'s primitives and meshes."""
    prims = [s for s in obj.shapes if s.kind in PRIMITIVE_TYPES]
    meshes = [s for s in obj.shapes if s.kind == 'mesh']
    if len(prims) + len(meshes) != len(obj.shapes):
        raise SceneError(f'{obj.id}: only primitives and meshes can be exported')
    return {'header': _header(), 'pose': pose_data(Pose()), 'id': obj.id,
            'type': {'key': '', 'db': ''},
            'primitives': [{'type': PRIMITIVE_TYPES[s.kind],
                            'dimensions': [float(d) for d in s.dims]} for s in prims],
            'primitive_poses': [pose_data(s.pose) for s in prims],
            'meshes': [{'triangles': [{'vertex_indices': [int(i) for i in f]}
                                      for f in np.asarray(s.faces)],
                        'vertices': [_xyz(v) for v in np.asarray(s.vertices)]}
                       for s in meshes],
            'mesh_poses': [pose_data(s.pose) for s in meshes],
            'planes': [], 'plane_poses': [], 'subframe_names': [], 'subframe_poses': [],
            'operation': 0}


def task_state(scene: Scene, robot: RobotModel) -> dict[str, float]:
    """Every joint of the task's robot state: the planned joints at the start, the others at
    the values the robot locks them to (what the importer locks them to again)."""
    q = robot.q_from_names(list(scene.start), list(scene.start.values()), f'{scene.name}.start')
    return {**dict(zip(robot.joint_names, q.tolist())), **robot.locked_values}


def planning_scene_data(scene: Scene, robot: RobotModel) -> dict:
    """The ``moveit_msgs/PlanningScene`` of ``scene`` (every object, start as robot state)."""
    return {'name': scene.name, 'robot_state': robot_state_data(task_state(scene, robot)),
            'robot_model_name': 'panda', 'fixed_frame_transforms': [],
            'allowed_collision_matrix': {'entry_names': [], 'entry_values': [],
                                         'default_entry_names': [], 'default_entry_values': []},
            'link_padding': [], 'link_scale': [], 'object_colors': [],
            'world': {'collision_objects': [collision_object_data(o) for o in scene.objects],
                      'octomap': {'header': _header(), 'origin': pose_data(Pose()),
                                  'octomap': {'header': _header(), 'binary': True,
                                              'id': 'OcTree', 'resolution': 0.1, 'data': []}}},
            'is_diff': False}  # an empty octomap: MoveIt adds nothing for it


def _constraints(**kinds) -> dict:
    out = {'name': '', 'joint_constraints': [], 'position_constraints': [],
           'orientation_constraints': [], 'visibility_constraints': []}
    out.update(kinds)
    return out


def _joint_goal_data(names: Sequence[str], values: Sequence[float]) -> dict:
    return _constraints(joint_constraints=[
        {'joint_name': j, 'position': float(v), 'tolerance_above': JOINT_GOAL_TOLERANCE_RAD,
         'tolerance_below': JOINT_GOAL_TOLERANCE_RAD, 'weight': 1.0}
        for j, v in zip(names, values)])


def goal_constraints_data(goal: GoalRegion, frame: str, free_seeds: Sequence[bool] | None = None
                          ) -> list[dict]:
    """``goal_constraints`` of the goal (see the module doc): a ``joint`` goal's configuration,
    or the region then one joint goal per seed that ``free_seeds`` (None: all) keeps."""
    if goal.is_joint:
        return [_joint_goal_data(goal.seed_joints, goal.seeds[0])]
    region = {'primitives': [{'type': PRIMITIVE_TYPES['box'], 'dimensions': [
        2.0 * float(h) for h in goal.position_tolerance_m]}],
              'primitive_poses': [pose_data(goal.center)], 'meshes': [], 'mesh_poses': []}
    position = {'header': _header(frame), 'link_name': goal.link,
                'target_point_offset': _xyz(goal.tool_offset.position_m),
                'constraint_region': region, 'weight': 1.0}
    tol = [min(float(t), math.pi) for t in goal.orientation_tolerance_rad]
    orientation = {'header': _header(frame), 'orientation': _quat(goal.center.quat_xyzw),
                   'link_name': goal.link, 'absolute_x_axis_tolerance': tol[0],
                   'absolute_y_axis_tolerance': tol[1], 'absolute_z_axis_tolerance': tol[2],
                   'parameterization': ROTATION_VECTOR, 'weight': 1.0}
    out = [_constraints(position_constraints=[position], orientation_constraints=[orientation])]
    keep = free_seeds if free_seeds is not None else [True] * len(goal.seeds)
    out += [_joint_goal_data(goal.seed_joints, seed) for seed, ok in zip(goal.seeds, keep) if ok]
    return out


def free_seeds(scene: Scene, robot: RobotModel) -> list[bool]:
    """Whether each seed of ``scene``'s goal region is collision-free in the scene (its objects,
    the attack's boxes included)."""
    from advocc_ros.kinematics.ik import seed_configurations
    from advocc_ros.model.collision import CollisionWorld

    seeds = seed_configurations(robot, scene.goal)
    if not len(seeds):
        return [True] * len(scene.goal.seeds)
    return (~CollisionWorld(robot, scene.shapes).collisions_batch(seeds)).tolist()


def request_data(scene: Scene, robot: RobotModel, planning_time_s: float = 5.0,
                 planner_id: str = 'RRTConnectkConfigDefault') -> dict:
    """The ``moveit_msgs/MotionPlanRequest`` of ``scene``'s task."""
    return {
        'workspace_parameters': {'header': _header(), 'min_corner': _xyz((-1, -1, -1)),
                                 'max_corner': _xyz((1, 1, 1))},
        'start_state': robot_state_data(task_state(scene, robot)),
        'goal_constraints': goal_constraints_data(
            scene.goal, base_frame(robot),
            None if scene.goal.is_joint else free_seeds(scene, robot)),
        'path_constraints': _constraints(),
        'trajectory_constraints': {'constraints': []}, 'reference_trajectories': [],
        'pipeline_id': '', 'planner_id': planner_id, 'group_name': scene.robot.moveit_group,
        'num_planning_attempts': 1, 'allowed_planning_time': float(planning_time_s),
        'max_velocity_scaling_factor': 1.0, 'max_acceleration_scaling_factor': 1.0,
        'cartesian_speed_end_effector_link': '', 'max_cartesian_speed': 0.0}


def _duration(t_s: float) -> dict:
    sec = math.floor(t_s)
    return {'sec': int(sec), 'nanosec': int(round((t_s - sec) * 1e9)) % 1_000_000_000}


def trajectory_data(joint_names: Sequence[str], waypoints: np.ndarray,
                    velocity_limits: np.ndarray) -> dict:
    """A ``moveit_msgs/RobotTrajectory`` through ``waypoints`` (N, nq) [rad], each segment
    timed by its slowest joint at ``velocity_limits`` [rad/s]."""
    waypoints = np.asarray(waypoints, dtype=float)
    limits = np.asarray(velocity_limits, dtype=float)
    limits = np.where(limits > 0, limits, 1.0)  # a URDF without limits: 1 rad/s
    steps = np.abs(np.diff(waypoints, axis=0)) / limits
    times = np.concatenate([[0.0], np.cumsum(steps.max(axis=1) if len(steps) else [])])
    points = [{'positions': [float(v) for v in q], 'velocities': [], 'accelerations': [],
               'effort': [], 'time_from_start': _duration(t)} for q, t in zip(waypoints, times)]
    return {'joint_trajectory': {'header': _header(), 'joint_names': list(joint_names),
                                 'points': points},
            'multi_dof_joint_trajectory': {'header': _header(), 'joint_names': [],
                                           'points': []}}


def load_trajectory(path: str | pathlib.Path) -> tuple[tuple[str, ...], np.ndarray]:
    """(joint names, (N, nq) positions) of a ``RobotTrajectory`` YAML file."""
    where = str(path)
    data = as_mapping(read_yaml(path), where)
    traj = as_mapping(data.get('joint_trajectory'), f'{where}: joint_trajectory')
    names = as_list(traj.get('joint_names'), f'{where}: joint_trajectory.joint_names')
    if not names or not all(isinstance(n, str) and n for n in names):
        raise SceneError(f'{where}: joint_trajectory.joint_names: expected joint names, got '
                         f'{names!r}')
    points = as_list(traj.get('points'), f'{where}: joint_trajectory.points')
    if not points:
        raise SceneError(f'{where}: joint_trajectory.points: no points')
    rows = []
    for k, point in enumerate(points):
        w = f'{where}: joint_trajectory.points[{k}]'
        row = floats(as_mapping(point, w).get('positions'), f'{w}.positions')
        if len(row) != len(names):
            raise SceneError(f'{w}.positions: {len(row)} values for {len(names)} joints')
        rows.append(row)
    return tuple(names), np.array(rows)


def write_problem(out_dir: str | pathlib.Path, index: int, scene: Scene, robot: RobotModel,
                  joint_names: Sequence[str], waypoints: np.ndarray,
                  planning_time_s: float = 5.0) -> ProblemFiles:
    """Problem ``index`` of ``scene`` (its objects include the attack's boxes) and its
    solution path into ``out_dir`` (atomic files; the folder is created)."""
    check_exportable(scene)
    if tuple(joint_names) != robot.joint_names:
        raise SceneError(f'witness joints {list(joint_names)} are not the robot\'s planned '
                         f'joints {list(robot.joint_names)}')
    files = problem_files(out_dir, index)
    files.scene.parent.mkdir(parents=True, exist_ok=True)
    save_yaml_atomic(files.scene, planning_scene_data(scene, robot))
    save_yaml_atomic(files.request, request_data(scene, robot, planning_time_s))
    save_yaml_atomic(files.trajectory, trajectory_data(
        joint_names, waypoints, robot.model.velocityLimit))
    return files
