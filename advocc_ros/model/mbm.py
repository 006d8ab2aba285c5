"""Import of MotionBenchMaker problems: MoveIt ``PlanningScene`` and ``MotionPlanRequest`` YAML.

MotionBenchMaker (Chamzas et al., RA-L 2022) ships each problem as a scene file (a MoveIt
``PlanningScene`` dump, ``sceneNNNN.yaml``) and a request file (``requestNNNN.yaml``) whose goal
is a joint configuration. Our attack needs a *goal region*, so the region is built around the
end-effector pose of that configuration (forward kinematics) with tolerances the user chooses:
the request fixes where the robot must go, the tolerances say how precisely, as in a
tolerance-aware pick.

Accepted forms (both the robowflex/MotionBenchMaker flavour and the ROS-message flavour):
- ``position: [x, y, z]`` or ``{x: .., y: .., z: ..}``; ``orientation: [x, y, z, w]`` or
  ``{x, y, z, w}``;
- primitive ``type``: ``box | sphere | cylinder`` or shape_msgs values ``1 | 2 | 3``;
  ``dimensions``: box ``[x, y, z]``, sphere ``[radius]``, cylinder ``[height, radius]``;
- an object's optional ``pose`` is composed with its ``primitive_poses`` (MoveIt >= Noetic);
- ``meshes[]{vertices, triangles}`` with ``mesh_poses`` (inline triangle meshes);
- ``header.frame_id``: empty, ``world`` (assumed to coincide with the robot base, as in
  MotionBenchMaker's fixed-base robots) or the base frame itself; other frames are refused
  rather than silently mis-placed.
Everything else in a dump (allowed collision matrix, colours, octomap, ...) is ignored.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.model.robot import RobotError, RobotModel, RobotSpec, load_robot
from advocc_ros.model.scene import (GoalRegion, Pose, Scene, SceneError, SceneObject, Shape,
                                    finite_array, make_mesh_shape, read_yaml)

_PRIMITIVES = {'box': 'box', 'sphere': 'sphere', 'cylinder': 'cylinder',
               1: 'box', 2: 'sphere', 3: 'cylinder'}
_DIMS = {'box': 3, 'sphere': 1, 'cylinder': 2}
_WORLD_FRAMES = ('', 'world', '/world')
_OK_OPERATIONS = (None, 0, 2, 'add', 'append', 'ADD', 'APPEND')


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


def is_mbm_scene(data: Any) -> bool:
    """Whether parsed YAML looks like a MoveIt ``PlanningScene`` dump rather than our format."""
    return isinstance(data, dict) and 'objects' not in data and (
        'world' in data or 'robot_state' in data or 'robot_model_name' in data)


# --------------------------------------------------------------------------------------------
# Field readers: each names the file and field of whatever is malformed.

def _mapping(data: Any, where: str) -> dict:
    if not isinstance(data, dict):
        raise SceneError(f'{where}: expected a mapping, got {type(data).__name__}')
    return data


def _list(data: Any, where: str) -> list:
    if data is None:
        return []
    if not isinstance(data, list):
        raise SceneError(f'{where}: expected a list, got {type(data).__name__}')
    return data


def _numbers(data: Any, where: str, keys: str) -> np.ndarray:
    """A vector from ``[a, b, ...]`` or ``{a: .., b: ..}`` (missing dict keys are an error)."""
    if isinstance(data, dict):
        missing = [k for k in keys if k not in data]
        if missing:
            raise SceneError(f'{where}: missing {missing}')
        data = [data[k] for k in keys]
    if not isinstance(data, (list, tuple)) or len(data) != len(keys):
        raise SceneError(f'{where}: expected {len(keys)} numbers ({",".join(keys)}), got '
                         f'{data!r}')
    return finite_array(data, where)


def _floats(data: Any, where: str) -> np.ndarray:
    """A list of finite numbers of any length."""
    if not isinstance(data, list):
        raise SceneError(f'{where}: expected a list of numbers, got {data!r}')
    return finite_array(data, where, n=len(data))


def _pose(data: Any, where: str) -> pin.SE3:
    if data is None:
        return pin.SE3.Identity()
    data = _mapping(data, where)
    pos = _numbers(data.get('position', [0, 0, 0]), f'{where}.position', 'xyz')
    quat = _numbers(data.get('orientation', [0, 0, 0, 1]), f'{where}.orientation', 'xyzw')
    norm = np.linalg.norm(quat)
    if norm < 1e-6:
        raise SceneError(f'{where}.orientation: zero quaternion')
    x, y, z, w = quat / norm
    return pin.SE3(pin.Quaternion(w, x, y, z).matrix(), pos)


def _check_frame(obj: dict, where: str, base_frame: str) -> None:
    header = obj.get('header')
    if header is None:
        return
    frame = _mapping(header, f'{where}.header').get('frame_id', '')
    if frame not in _WORLD_FRAMES + (base_frame, '/' + base_frame):
        raise SceneError(f'{where}.header.frame_id: {frame!r} is not the robot base frame '
                         f'({base_frame!r}) or "world"; transform the scene first')


def _primitive(prim: Any, where: str, pose: pin.SE3) -> Shape:
    prim = _mapping(prim, where)
    raw = prim.get('type')
    kind = _PRIMITIVES.get(raw.lower() if isinstance(raw, str) else raw)
    if kind is None:
        raise SceneError(f'{where}.type: expected box, sphere or cylinder (or 1, 2, 3), got '
                         f'{raw!r}')
    dims = prim.get('dimensions')
    if not isinstance(dims, list) or len(dims) != _DIMS[kind]:
        layout = {'box': '[x, y, z]', 'sphere': '[radius]', 'cylinder': '[height, radius]'}[kind]
        raise SceneError(f'{where}.dimensions: a {kind} needs {layout}, got {dims!r}')
    arr = _floats(dims, f'{where}.dimensions')
    if not np.all(arr > 0):
        raise SceneError(f'{where}.dimensions: values must be > 0, got {dims!r}')
    return Shape(kind, tuple(arr.tolist()), Pose.from_se3(pose))


def _mesh(mesh: Any, where: str, pose: pin.SE3) -> Shape:
    mesh = _mapping(mesh, where)
    vertices = np.array([_numbers(v, f'{where}.vertices[{k}]', 'xyz')
                         for k, v in enumerate(_list(mesh.get('vertices'), f'{where}.vertices'))])
    faces = []
    for k, tri in enumerate(_list(mesh.get('triangles'), f'{where}.triangles')):
        idx = tri.get('vertex_indices') if isinstance(tri, dict) else tri
        if not (isinstance(idx, list) and len(idx) == 3 and all(isinstance(i, int) for i in idx)):
            raise SceneError(f'{where}.triangles[{k}]: expected 3 vertex indices, got {tri!r}')
        faces.append(idx)
    return make_mesh_shape(vertices.reshape(-1, 3), np.array(faces, dtype=np.int64).reshape(-1, 3),
                           Pose.from_se3(pose), where)


def _posed_parts(obj: dict, where: str, T_obj: pin.SE3, items: str, poses: str
                 ) -> list[tuple[Any, str, pin.SE3]]:
    """(part, where, ``T_base_part``) of each primitive or mesh with its pose."""
    parts = _list(obj.get(items), f'{where}.{items}')
    part_poses = _list(obj.get(poses), f'{where}.{poses}')
    if len(part_poses) != len(parts):
        raise SceneError(f'{where}.{poses}: {len(part_poses)} poses for {len(parts)} {items}')
    return [(p, f'{where}.{items}[{k}]', T_obj * _pose(part_poses[k], f'{where}.{poses}[{k}]'))
            for k, p in enumerate(parts)]


def objects_from_planning_scene(data: Any, where: str, base_frame: str = 'panda_link0'
                                ) -> tuple[SceneObject, ...]:
    """Collision objects of a ``PlanningScene`` mapping, in the robot base frame."""
    data = _mapping(data, where)
    world = data.get('world')
    if world is None:
        return ()
    world = _mapping(world, f'{where}: world')
    objects, seen = [], set()
    entries = _list(world.get('collision_objects'), f'{where}: world.collision_objects')
    for i, obj in enumerate(entries):
        w = f'{where}: world.collision_objects[{i}]'
        obj = _mapping(obj, w)
        obj_id = obj.get('id')
        if not isinstance(obj_id, str) or not obj_id:
            raise SceneError(f'{w}.id: expected a non-empty string, got {obj_id!r}')
        if obj_id in seen:
            raise SceneError(f'{w}.id: duplicate id {obj_id!r}')
        seen.add(obj_id)
        if obj.get('operation') not in _OK_OPERATIONS:
            raise SceneError(f'{w}.operation: a scene dump holds ADD/APPEND objects, got '
                             f'{obj.get("operation")!r}')
        _check_frame(obj, w, base_frame)
        T_obj = _pose(obj.get('pose'), f'{w}.pose')
        shapes = [_primitive(*part)
                  for part in _posed_parts(obj, w, T_obj, 'primitives', 'primitive_poses')]
        shapes += [_mesh(*part) for part in _posed_parts(obj, w, T_obj, 'meshes', 'mesh_poses')]
        if obj.get('planes'):
            raise SceneError(f'{w}.planes: infinite planes are not supported; use a thin box')
        if not shapes:
            raise SceneError(f'{w}: no primitives or meshes')
        objects.append(SceneObject(obj_id, tuple(shapes)))
    return tuple(objects)


def _joint_state(data: Any, where: str, robot: RobotModel) -> dict[str, float]:
    data = _mapping(data, where)
    names = _list(data.get('name'), f'{where}.name')
    positions = _list(data.get('position'), f'{where}.position')
    if not names:
        raise SceneError(f'{where}.name: no joint names')
    if not all(isinstance(n, str) for n in names):
        raise SceneError(f'{where}.name: expected joint names (strings), got {names!r}')
    try:
        q = robot.q_from_names(names, list(_floats(positions, f'{where}.position')), where)
    except RobotError as exc:
        raise SceneError(str(exc)) from None
    return dict(zip(robot.joint_names, q.tolist()))


@dataclasses.dataclass(frozen=True)
class MbmRequest:
    """What we use of a ``MotionPlanRequest``: start and goal configurations by joint name."""

    start: dict[str, float] | None
    goal: dict[str, float]


def load_request(path: str | pathlib.Path, robot: RobotModel) -> MbmRequest:
    """Start state and joint-space goal of a MotionBenchMaker ``requestNNNN.yaml``.

    The goal is the first ``goal_constraints`` entry; its ``joint_constraints`` must cover every
    planned joint (tolerances there are ignored: the goal region's tolerances replace them).
    """
    path = pathlib.Path(path)
    where = str(path)
    data = _mapping(read_yaml(path), where)
    start = None
    if data.get('start_state') is not None:
        state = _mapping(data['start_state'], f'{where}: start_state')
        if state.get('joint_state') is not None:
            start = _joint_state(state['joint_state'], f'{where}: start_state.joint_state', robot)
    goals = _list(data.get('goal_constraints'), f'{where}: goal_constraints')
    if not goals:
        raise SceneError(f'{where}: goal_constraints: missing or empty (a joint goal is needed)')
    w = f'{where}: goal_constraints[0]'
    constraints = _list(_mapping(goals[0], w).get('joint_constraints'), f'{w}.joint_constraints')
    if not constraints:
        raise SceneError(f'{w}.joint_constraints: missing or empty (only joint-space goals are '
                         'supported)')
    names, positions = [], []
    for k, jc in enumerate(constraints):
        jc = _mapping(jc, f'{w}.joint_constraints[{k}]')
        name = jc.get('joint_name')
        if not isinstance(name, str) or not name:
            raise SceneError(f'{w}.joint_constraints[{k}].joint_name: expected a joint name, '
                             f'got {name!r}')
        if jc.get('position') is None:
            raise SceneError(f'{w}.joint_constraints[{k}].position: missing')
        names.append(name)
        positions.append(float(_numbers([jc.get('position')],
                                        f'{w}.joint_constraints[{k}].position', 'p')[0]))
    goal = _joint_state({'name': names, 'position': positions}, f'{w}.joint_constraints', robot)
    return MbmRequest(start, goal)


def goal_region_at(robot: RobotModel, q_goal: dict[str, float],
                   tolerance: GoalTolerance = GoalTolerance()) -> GoalRegion:
    """Goal region centred on the end-effector pose of ``q_goal`` (forward kinematics)."""
    q = robot.q_from_names(list(q_goal), list(q_goal.values()), 'goal configuration')
    return GoalRegion(center=Pose.from_se3(robot.ee_pose(q)),
                      position_tolerance_m=tuple(tolerance.position_m),
                      orientation_tolerance_rad=tuple(tolerance.orientation_rad),
                      link=robot.spec.ee_link)


def base_frame(robot: RobotModel) -> str:
    """Name of the robot's root link (the frame our scenes are expressed in)."""
    return next(f.name for f in robot.model.frames if f.type == pin.FrameType.BODY)


def apply_request(scene: Scene, request_path: str | pathlib.Path,
                  tolerance: GoalTolerance = GoalTolerance()) -> Scene:
    """``scene`` with the request's start (if it has one) and a goal region around its goal."""
    robot = load_robot(scene.robot)
    request = load_request(request_path, robot)
    return dataclasses.replace(scene, start=request.start or scene.start,
                               goal=goal_region_at(robot, request.goal, tolerance))


def load_mbm_scene(scene_path: str | pathlib.Path,
                   request_path: str | pathlib.Path | None = None,
                   tolerance: GoalTolerance = GoalTolerance(),
                   robot: RobotSpec = RobotSpec()) -> Scene:
    """Our ``Scene`` from a MotionBenchMaker scene file and (optionally) its request file.

    Start: the request's ``start_state``, else the scene's ``robot_state``, else none. Goal: a
    region around the request goal's end-effector pose with ``tolerance``, else none.
    """
    path = pathlib.Path(scene_path)
    where = str(path)
    data = _mapping(read_yaml(path), where)
    model = load_robot(robot)
    frame = base_frame(model)
    objects = objects_from_planning_scene(data, where, frame)
    start = None
    if data.get('robot_state') is not None:
        state = _mapping(data['robot_state'], f'{where}: robot_state')
        if state.get('joint_state') is not None:
            start = _joint_state(state['joint_state'], f'{where}: robot_state.joint_state', model)
    name = data.get('name')  # MoveIt dumps often say "(noname)+": use the file name then
    if not isinstance(name, str) or not name or name.startswith('('):
        name = path.stem
    scene = Scene(objects=objects, start=start, robot=robot, name=name, frame=frame)
    if request_path is not None:
        scene = apply_request(scene, request_path, tolerance)
    return scene


def load_any_scene(scene: str | pathlib.Path, request: str | pathlib.Path | None = None,
                   goal_tol: GoalTolerance | str | None = None) -> Scene:
    """A scene from our YAML or a MotionBenchMaker scene file, with an optional request.

    ``scene`` is a path or a shipped scene name (``table_pick``). The file's format is told by
    its content (``world``/``robot_state`` keys: a ``PlanningScene`` dump). With ``request``,
    its start (if any) and a goal region around its goal replace the scene's; without one,
    ``goal_tol`` replaces the tolerances of the scene's own goal region.
    """
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import scene_from_data

    path = scene_path(str(scene))
    data = read_yaml(path)
    if is_mbm_scene(data):
        out = load_mbm_scene(path, None)
    else:
        out = scene_from_data(data, str(path), path.parent)
    if request is not None:
        if isinstance(goal_tol, str):
            goal_tol = parse_goal_tolerance(goal_tol)
        out = apply_request(out, request, goal_tol or GoalTolerance())
    elif goal_tol is not None:
        if out.goal is None:
            raise SceneError(f'{path}: --goal-tol given but the scene has no goal region (give '
                             'a --request with a goal configuration)')
        if isinstance(goal_tol, str):
            goal_tol = parse_goal_tolerance(goal_tol, GoalTolerance(
                out.goal.position_tolerance_m, out.goal.orientation_tolerance_rad))
        out = dataclasses.replace(out, goal=dataclasses.replace(
            out.goal, position_tolerance_m=tuple(goal_tol.position_m),
            orientation_tolerance_rad=tuple(goal_tol.orientation_rad)))
    return out
