"""Import of MotionBenchMaker problems: MoveIt ``PlanningScene`` and ``MotionPlanRequest`` YAML.

MotionBenchMaker (Chamzas et al., RA-L 2022) ships each problem as a scene file (a MoveIt
``PlanningScene`` dump, ``sceneNNNN.yaml``) and a request file (``requestNNNN.yaml``, read by
``mbm_request``) whose goal is a joint configuration or a pose constraint. The robot state of the
task (the request's ``start_state``, else the scene's ``robot_state``) carries every joint: the
ones outside the planning group (the Panda's fingers) lock the robot's (docs/design.md, "The
robot state that comes with a task").

Accepted forms (both the robowflex/MotionBenchMaker flavour and the ROS-message flavour):
- ``position: [x, y, z]`` or ``{x: .., y: .., z: ..}``; ``orientation: [x, y, z, w]`` or
  ``{x, y, z, w}``;
- primitive ``type``: ``box | sphere | cylinder`` or shape_msgs values ``1 | 2 | 3``;
  ``dimensions``: box ``[x, y, z]``, sphere ``[radius]``, cylinder ``[height, radius]``;
- an object's optional ``pose`` is composed with its ``primitive_poses`` (MoveIt >= Noetic);
- ``meshes[]{vertices, triangles}`` with ``mesh_poses`` (inline triangle meshes);
- ``header.frame_id``: the base frame itself, or empty / ``world``: placed through the robot
  state's ``multi_dof_joint_state`` (MoveIt's ``virtual_joint``, world -> base; identity when
  absent); other frames are refused rather than silently mis-placed.
Everything else in a dump (allowed collision matrix, colours, octomap, ...) is ignored.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.formats.mbm_fields import (ADD_OPERATIONS, WORLD_FRAMES, as_list, as_mapping,
                                           base_frame, joint_state, numbers, pose_se3,
                                           primitive_shape, virtual_joint)
from advocc_ros.formats.mbm_request import (GoalTolerance, goal_region_at, load_request,
                                            parse_goal_tolerance)
from advocc_ros.model.robot import RobotSpec, load_robot
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import Scene, SceneObject, read_yaml
from advocc_ros.model.shapes import Shape, make_mesh_shape


def is_mbm_scene(data: Any) -> bool:
    """Whether parsed YAML looks like a MoveIt ``PlanningScene`` dump rather than our format."""
    return isinstance(data, dict) and 'objects' not in data and (
        'world' in data or 'robot_state' in data or 'robot_model_name' in data)


# --------------------------------------------------------------------------------------------
# Field readers: each names the file and field of whatever is malformed.

def _frame_of(obj: dict, where: str, base_frame: str, T_base_world: pin.SE3) -> pin.SE3:
    """``T_base_frame`` of an object's ``header.frame_id``: the base itself or the world."""
    header = obj.get('header')
    if header is None:
        return T_base_world
    frame = as_mapping(header, f'{where}.header').get('frame_id', '')
    if frame in (base_frame, '/' + base_frame):
        return pin.SE3.Identity()
    if frame not in WORLD_FRAMES:
        raise SceneError(f'{where}.header.frame_id: {frame!r} is not the robot base frame '
                         f'({base_frame!r}) or "world"; transform the scene first')
    return T_base_world


def _mesh(mesh: Any, where: str, pose: pin.SE3) -> Shape:
    mesh = as_mapping(mesh, where)
    rows = as_list(mesh.get('vertices'), f'{where}.vertices')
    vertices = np.array([numbers(v, f'{where}.vertices[{k}]', 'xyz') for k, v in enumerate(rows)])
    faces = []
    for k, tri in enumerate(as_list(mesh.get('triangles'), f'{where}.triangles')):
        idx = tri.get('vertex_indices') if isinstance(tri, dict) else tri
        if not (isinstance(idx, list) and len(idx) == 3 and all(isinstance(i, int) for i in idx)):
            raise SceneError(f'{where}.triangles[{k}]: expected 3 vertex indices, got {tri!r}')
        faces.append(idx)
    return make_mesh_shape(vertices.reshape(-1, 3), np.array(faces, dtype=np.int64).reshape(-1, 3),
                           Pose.from_se3(pose), where)


def _posed_parts(obj: dict, where: str, T_obj: pin.SE3, items: str, poses: str
                 ) -> list[tuple[Any, str, pin.SE3]]:
    """(part, where, ``T_base_part``) of each primitive or mesh with its pose."""
    parts = as_list(obj.get(items), f'{where}.{items}')
    part_poses = as_list(obj.get(poses), f'{where}.{poses}')
    if len(part_poses) != len(parts):
        raise SceneError(f'{where}.{poses}: {len(part_poses)} poses for {len(parts)} {items}')
    return [(p, f'{where}.{items}[{k}]', T_obj * pose_se3(part_poses[k], f'{where}.{poses}[{k}]'))
            for k, p in enumerate(parts)]


def objects_from_planning_scene(data: Any, where: str, base_frame: str = RobotSpec.base_frame,
                                T_world_base: pin.SE3 | None = None
                                ) -> tuple[SceneObject, ...]:
    """Collision objects of a ``PlanningScene`` mapping, in the robot base frame.

    ``T_world_base``: where the base is in the world (MoveIt's ``virtual_joint``; default: the
    scene's own ``robot_state.multi_dof_joint_state``, else identity)."""
    data = as_mapping(data, where)
    world = data.get('world')
    if world is None:
        return ()
    if T_world_base is None:
        T_world_base = virtual_joint(data.get('robot_state'), f'{where}: robot_state')
    T_base_world = T_world_base.inverse()
    world = as_mapping(world, f'{where}: world')
    objects, seen = [], set()
    entries = as_list(world.get('collision_objects'), f'{where}: world.collision_objects')
    for i, obj in enumerate(entries):
        w = f'{where}: world.collision_objects[{i}]'
        obj = as_mapping(obj, w)
        obj_id = obj.get('id')
        if not isinstance(obj_id, str) or not obj_id:
            raise SceneError(f'{w}.id: expected a non-empty string, got {obj_id!r}')
        if obj_id in seen:
            raise SceneError(f'{w}.id: duplicate id {obj_id!r}')
        seen.add(obj_id)
        if obj.get('operation') not in ADD_OPERATIONS:
            raise SceneError(f'{w}.operation: a scene dump holds ADD/APPEND objects, got '
                             f'{obj.get("operation")!r}')
        T_obj = (_frame_of(obj, w, base_frame, T_base_world)
                 * pose_se3(obj.get('pose'), f'{w}.pose'))
        shapes = [primitive_shape(*part)
                  for part in _posed_parts(obj, w, T_obj, 'primitives', 'primitive_poses')]
        shapes += [_mesh(*part) for part in _posed_parts(obj, w, T_obj, 'meshes', 'mesh_poses')]
        if obj.get('planes'):
            raise SceneError(f'{w}.planes: infinite planes are not supported; use a thin box')
        if not shapes:
            raise SceneError(f'{w}: no primitives or meshes')
        objects.append(SceneObject(obj_id, tuple(shapes)))
    return tuple(objects)


def apply_request(scene: Scene, request_path: str | pathlib.Path,
                  tolerance: GoalTolerance = GoalTolerance(),
                  T_world_base: pin.SE3 | None = None, goal_form: str | None = None) -> Scene:
    """``scene`` with the request's start (if it has one; its joints outside the planning group
    lock the robot's) and its goal: a pose goal's own region; a joint goal in ``goal_form``
    (None: ``joint``), the configuration itself or a region with ``tolerance`` around its
    end-effector pose. ``SceneError`` for the ``joint`` form of a pose goal."""
    request = load_request(request_path, load_robot(scene.robot), T_world_base)
    scene = dataclasses.replace(scene, start=request.start or scene.start)
    if request.goal_region is not None:
        if goal_form == 'joint':
            raise SceneError(f'{request_path}: the goal is a pose region, not a joint '
                             'configuration: the joint goal form needs a joint goal (use '
                             '--goal-form region)')
        return dataclasses.replace(scene, goal=request.goal_region)
    goal = goal_region_at(load_robot(scene.robot), request.goal, tolerance,
                          goal_form or 'joint')
    return dataclasses.replace(scene, goal=goal)


def load_mbm_scene(scene_path: str | pathlib.Path,
                   request_path: str | pathlib.Path | None = None,
                   tolerance: GoalTolerance = GoalTolerance(),
                   robot: RobotSpec = RobotSpec(), goal_form: str | None = None) -> Scene:
    """Our ``Scene`` from a MotionBenchMaker scene file and (optionally) its request file.

    Start: the request's ``start_state``, else the scene's ``robot_state``, else none. Goal: the
    request's (``apply_request``: ``goal_form``, ``tolerance``), else none.
    """
    path = pathlib.Path(scene_path)
    where = str(path)
    data = as_mapping(read_yaml(path), where)
    model = load_robot(robot)
    frame = base_frame(model)
    start, T_world_base = None, pin.SE3.Identity()
    if data.get('robot_state') is not None:
        state = as_mapping(data['robot_state'], f'{where}: robot_state')
        if state.get('joint_state') is not None:
            start = joint_state(state['joint_state'], f'{where}: robot_state.joint_state', model)
        T_world_base = virtual_joint(state, f'{where}: robot_state')
    objects = objects_from_planning_scene(data, where, frame, T_world_base)
    name = data.get('name')  # MoveIt dumps often say "(noname)+": use the file name then
    if not isinstance(name, str) or not name or name.startswith('('):
        name = path.stem
    scene = Scene(objects=objects, start=start, robot=robot, name=name, frame=frame)
    if request_path is not None:
        scene = apply_request(scene, request_path, tolerance, T_world_base, goal_form)
    return scene


def load_any_scene(scene: str | pathlib.Path, request: str | pathlib.Path | None = None,
                   goal_tol: GoalTolerance | str | None = None, goal_form: str | None = None
                   ) -> Scene:
    """A scene from our YAML or a MotionBenchMaker scene file, with an optional request.

    ``scene`` is a path or a shipped scene name (``table_pick``). The file's format is told by
    its content (``world``/``robot_state`` keys: a ``PlanningScene`` dump). With ``request``,
    its start (if any) and its goal replace the scene's: a joint goal in ``goal_form`` (None:
    ``joint``; ``region``: a region with ``goal_tol`` around its end-effector pose), a pose
    goal's region; without one, ``goal_tol`` replaces the tolerances of the scene's own goal
    region, and ``goal_form`` ``joint`` is refused unless the scene's goal is one.
    """
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import scene_from_data

    path = scene_path(str(scene))
    data = read_yaml(path)
    if is_mbm_scene(data):
        if request is not None:
            if isinstance(goal_tol, str):
                goal_tol = parse_goal_tolerance(goal_tol)
            return load_mbm_scene(path, request, goal_tol or GoalTolerance(),
                                  goal_form=goal_form)
        out = load_mbm_scene(path, None)
    else:
        out = scene_from_data(data, str(path), path.parent)
    if request is not None:
        if isinstance(goal_tol, str):
            goal_tol = parse_goal_tolerance(goal_tol)
        return apply_request(out, request, goal_tol or GoalTolerance(), goal_form=goal_form)
    if goal_form is not None and out.goal is not None and out.goal.form != goal_form:
        raise SceneError(f'{path}: its goal is in the {out.goal.form} form; the {goal_form} '
                         'form needs a request with a joint goal (--request)')
    if goal_tol is not None:
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
