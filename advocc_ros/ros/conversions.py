"""Translations between ROS messages and core types, in one place.

Every ``*_from_msg`` validates what it reads (finite numbers, sane sizes) and raises
``SceneError`` / ``RobotError`` with a message naming the field, so nodes can turn it into an
error response.
"""

from __future__ import annotations

import numpy as np
from advocc_msgs.msg import (CollisionObject, GoalRegion as GoalRegionMsg, Obstacle as ObstacleMsg,
                             Scene as SceneMsg)
from advocc_msgs.srv import Attack, Plan
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Pose as PoseMsg, Quaternion
from sensor_msgs.msg import JointState
from shape_msgs.msg import Mesh, MeshTriangle, SolidPrimitive
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from advocc_ros.attack.types import DEFAULT_METHOD
from advocc_ros.limits import (MAX_JOINTS, MAX_MESH_TRIANGLES, MAX_MESH_VERTICES, MAX_OBJECTS,
                               MAX_SCENE_VERTICES, MAX_SHAPES)
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import Operation, Scene, SceneObject, make_box, objects_to_data
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.shapes import Shape, make_mesh_shape
from advocc_ros.ros.clouds import cloud_msg, scene_cloud, without_clouds
from advocc_ros.ros.errors import code_name


def pose_from_msg(msg: PoseMsg, where: str = 'pose') -> Pose:
    p, o = msg.position, msg.orientation
    return Pose.from_data({'position': [p.x, p.y, p.z], 'orientation': [o.x, o.y, o.z, o.w]},
                          where)


def pose_to_msg(pose: Pose) -> PoseMsg:
    x, y, z = pose.position_m
    qx, qy, qz, qw = pose.quat_xyzw
    return PoseMsg(position=Point(x=float(x), y=float(y), z=float(z)),
                   orientation=Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw)))


def goal_region_from_msg(msg: GoalRegionMsg, default_link: str, where: str = 'goal_region'
                         ) -> GoalRegion:
    """``default_link``: the link of a message that names none (the node's robot's ee link).
    A ``joint`` form message carries its goal configuration in ``joint_goal``."""
    joint = {}
    if msg.form:
        joint['form'] = msg.form
    if msg.form == 'joint':
        names, values = list(msg.joint_goal.name), list(msg.joint_goal.position)
        if not names or len(names) != len(values):
            raise SceneError(f'{where}.joint_goal: the joint form needs one position per named '
                             f'joint, got {len(names)} names and {len(values)} positions')
        joint['seeds'] = [dict(zip(names, values))]
    return GoalRegion.from_data({
        'link': msg.link_name or default_link,
        'center': {'position': [msg.center.position.x, msg.center.position.y,
                                msg.center.position.z],
                   'orientation': [msg.center.orientation.x, msg.center.orientation.y,
                                   msg.center.orientation.z, msg.center.orientation.w]},
        'position_tolerance': list(msg.position_tolerance),
        'orientation_tolerance': list(msg.orientation_tolerance),
        'tool_offset': {'position': [msg.tool_offset.position.x, msg.tool_offset.position.y,
                                     msg.tool_offset.position.z],
                        'orientation': [msg.tool_offset.orientation.x,
                                        msg.tool_offset.orientation.y,
                                        msg.tool_offset.orientation.z,
                                        msg.tool_offset.orientation.w]},
        **joint}, where)


def goal_region_to_msg(goal: GoalRegion, frame: str) -> GoalRegionMsg:
    msg = GoalRegionMsg()
    msg.header.frame_id = frame
    msg.link_name = goal.link
    msg.center = pose_to_msg(goal.center)
    msg.tool_offset = pose_to_msg(goal.tool_offset)
    msg.position_tolerance = [float(v) for v in goal.position_tolerance_m]
    msg.orientation_tolerance = [float(v) for v in goal.orientation_tolerance_rad]
    msg.form = goal.form
    if goal.is_joint:
        msg.joint_goal.name = list(goal.seed_joints)
        msg.joint_goal.position = [float(v) for v in goal.seeds[0]]
    return msg


def _shape_from_primitive(prim: SolidPrimitive, pose: Pose, where: str) -> Shape:
    dims = np.asarray(prim.dimensions, dtype=float)
    need = {SolidPrimitive.BOX: 3, SolidPrimitive.SPHERE: 1, SolidPrimitive.CYLINDER: 2}
    if prim.type not in need:
        raise SceneError(f'{where}.type: only BOX, SPHERE and CYLINDER are supported, '
                         f'got {prim.type}')
    if dims.shape != (need[prim.type],) or not np.all(np.isfinite(dims)) or np.any(dims <= 0):
        raise SceneError(f'{where}.dimensions: expected {need[prim.type]} finite positive '
                         f'values, got {dims.tolist()}')
    kind = {SolidPrimitive.BOX: 'box', SolidPrimitive.SPHERE: 'sphere',
            SolidPrimitive.CYLINDER: 'cylinder'}[prim.type]
    return Shape(kind, tuple(dims.tolist()), pose)


def operation_int(op: int | bytes) -> int:
    """A collision-object operation as an int: message fields and constants are ROS ``byte``
    (Python ``bytes``), as in MoveIt; ``scene.Operation`` values are ints."""
    return int.from_bytes(op, 'little') if isinstance(op, (bytes, bytearray)) else int(op)


def collision_object_from_msg(msg: CollisionObject, where: str = 'object'
                              ) -> tuple[int, SceneObject, Pose]:
    """(operation as ``scene.Operation`` int, object with shapes posed in the message frame,
    object pose)."""
    where = f'{where} {msg.id!r}'
    obj_pose = pose_from_msg(msg.pose, f'{where}.pose')
    T_obj = obj_pose.to_se3()
    if len(msg.primitives) != len(msg.primitive_poses):
        raise SceneError(f'{where}: {len(msg.primitives)} primitives but '
                         f'{len(msg.primitive_poses)} primitive_poses')
    if len(msg.meshes) != len(msg.mesh_poses):
        raise SceneError(f'{where}: {len(msg.meshes)} meshes but {len(msg.mesh_poses)} mesh_poses')
    _check_sizes([msg], where)
    shapes = []
    for i, (prim, pmsg) in enumerate(zip(msg.primitives, msg.primitive_poses)):
        local = pose_from_msg(pmsg, f'{where}.primitive_poses[{i}]')
        shapes.append(_shape_from_primitive(
            prim, Pose.from_se3(T_obj * local.to_se3()), f'{where}.primitives[{i}]'))
    for i, (mesh, mmsg) in enumerate(zip(msg.meshes, msg.mesh_poses)):
        local = pose_from_msg(mmsg, f'{where}.mesh_poses[{i}]')
        vertices = np.array([[v.x, v.y, v.z] for v in mesh.vertices], dtype=float).reshape(-1, 3)
        faces = np.array([list(t.vertex_indices) for t in mesh.triangles],
                         dtype=np.int64).reshape(-1, 3)
        shapes.append(make_mesh_shape(vertices, faces, Pose.from_se3(T_obj * local.to_se3()),
                                      f'{where}.meshes[{i}]'))
    operation = operation_int(msg.operation)
    if operation in (Operation.ADD, Operation.APPEND) and not shapes:
        raise SceneError(f'{where}: ADD/APPEND needs at least one primitive or mesh')
    return operation, SceneObject(msg.id, tuple(shapes)), obj_pose


def _check_sizes(msgs: list[CollisionObject], where: str) -> None:
    """Refuse oversized messages from their array lengths, before any per-element work."""
    shapes = sum(len(m.primitives) + len(m.meshes) for m in msgs)
    if shapes > MAX_SHAPES:
        raise SceneError(f'{where}: {shapes} primitives + meshes, limit {MAX_SHAPES}')
    total = 0
    for m in msgs:
        for i, mesh in enumerate(m.meshes):
            if len(mesh.vertices) > MAX_MESH_VERTICES:
                raise SceneError(f'{where}.meshes[{i}]: {len(mesh.vertices)} vertices, limit '
                                 f'{MAX_MESH_VERTICES}')
            if len(mesh.triangles) > MAX_MESH_TRIANGLES:
                raise SceneError(f'{where}.meshes[{i}]: {len(mesh.triangles)} triangles, limit '
                                 f'{MAX_MESH_TRIANGLES}')
            total += len(mesh.vertices)
    if total > MAX_SCENE_VERTICES:
        raise SceneError(f'{where}: {total} mesh vertices, limit {MAX_SCENE_VERTICES}')


def scene_from_msgs(msgs: list[CollisionObject], where: str = 'scene') -> tuple[SceneObject, ...]:
    """Objects of a request's scene list (each message must be an ADD)."""
    if len(msgs) > MAX_OBJECTS:
        raise SceneError(f'{where}: {len(msgs)} objects, limit {MAX_OBJECTS}')
    _check_sizes(msgs, where)
    objects = []
    for i, msg in enumerate(msgs):
        op, obj, _ = collision_object_from_msg(msg, f'{where}[{i}]')
        if op != Operation.ADD:
            raise SceneError(f'{where}[{i}]: only ADD objects can describe a scene')
        objects.append(obj)
    return tuple(objects)


def collision_object_to_msg(obj: SceneObject, frame: str,
                            operation: int | bytes = Operation.ADD) -> CollisionObject:
    """Message for ``obj``; shapes are posed relative to an identity object pose."""
    operation = operation_int(operation)
    msg = CollisionObject(id=obj.id, operation=bytes([operation]))
    msg.header.frame_id = frame
    for shape in obj.shapes if operation != Operation.REMOVE else ():
        if shape.kind == 'cloud':
            raise SceneError(f'object {obj.id!r}: a point cloud has no CollisionObject form; '
                             'send it as sensor_msgs/PointCloud2 (/advocc/cloud)')
        if shape.kind == 'mesh':
            msg.meshes.append(Mesh(
                triangles=[MeshTriangle(vertex_indices=[int(i) for i in f])
                           for f in shape.faces],
                vertices=[Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))
                          for v in shape.vertices]))
            msg.mesh_poses.append(pose_to_msg(shape.pose))
            continue
        kind = {'box': SolidPrimitive.BOX, 'sphere': SolidPrimitive.SPHERE,
                'cylinder': SolidPrimitive.CYLINDER}[shape.kind]
        msg.primitives.append(SolidPrimitive(type=kind, dimensions=list(shape.dims)))
        msg.primitive_poses.append(pose_to_msg(shape.pose))
    return msg


def q_from_joint_state(robot: RobotModel, msg: JointState, where: str = 'start_state'
                       ) -> np.ndarray:
    if len(msg.name) > MAX_JOINTS or len(msg.position) > MAX_JOINTS:
        raise RobotError(f'{where}: {len(msg.name)} names / {len(msg.position)} positions, '
                         f'limit {MAX_JOINTS}')
    return robot.q_from_names(list(msg.name), list(msg.position), where)


def obstacle_to_msg(obj: SceneObject, covered_mass: float) -> ObstacleMsg:
    shape = obj.shapes[0]
    return ObstacleMsg(id=obj.id, pose=pose_to_msg(shape.pose), size=list(shape.dims),
                       covered_mass=float(covered_mass))


def trajectory_to_msg(robot: RobotModel, path: np.ndarray, times_s: np.ndarray | None = None
                      ) -> JointTrajectory:
    """Joint trajectory of waypoints ``path`` (N, nq); ``times_s`` default to 0.1 s apart."""
    msg = JointTrajectory(joint_names=list(robot.joint_names))
    times_s = np.arange(len(path)) * 0.1 if times_s is None else times_s
    for q, t in zip(path, times_s):
        sec = int(t)
        msg.points.append(JointTrajectoryPoint(
            positions=[float(v) for v in q],
            time_from_start=Duration(sec=sec, nanosec=int(round((t - sec) * 1e9)))))
    return msg


def trajectory_from_msg(robot: RobotModel, msg: JointTrajectory) -> np.ndarray:
    """Waypoints (N, nq) in the robot's joint order."""
    return np.array([robot.q_from_names(list(msg.joint_names), list(p.positions),
                                        f'trajectory.points[{i}]')
                     for i, p in enumerate(msg.points)]).reshape(-1, robot.nq)


def joint_state_from_dict(positions: dict[str, float]) -> JointState:
    """A JointState naming the joints of ``positions`` (a scene's ``start``)."""
    return JointState(name=list(positions), position=[float(v) for v in positions.values()])


def scene_to_msg(scene: Scene) -> SceneMsg:
    """The ``/advocc/scene`` message of a scene: its objects and start state."""
    if scene.start is None:
        raise SceneError(f'scene {scene.name!r} has no start state')
    msg = SceneMsg(name=scene.name)
    msg.header.frame_id = scene.frame
    # Sensed clouds travel separately (/advocc/cloud, a request's cloud): see ros/clouds.py.
    msg.objects = [collision_object_to_msg(o, scene.frame) for o in without_clouds(scene.objects)]
    msg.start_state = joint_state_from_dict(scene.start)
    return msg


def attack_request_from_msgs(scene: SceneMsg, goal: GoalRegionMsg, budget: int,
                             method: str = DEFAULT_METHOD, box_size_m: float = 0.0,
                             seed: int = 0,
                             goal_policy: str = '') -> Attack.Request:
    """Attack.Request for a task as it arrives on ``/advocc/scene`` and ``/advocc/goal_region``
    (passed on unchanged: the heatmap server validates it)."""
    req = Attack.Request()
    req.scene = list(scene.objects)
    req.start_state = scene.start_state
    req.goal_region = goal
    req.budget, req.method, req.box_size, req.seed = int(budget), str(method), \
        float(box_size_m), int(seed)
    req.goal_policy = str(goal_policy)
    return req


def attack_request(scene: Scene, budget: int, method: str = DEFAULT_METHOD,
                   box_size_m: float = 0.0, seed: int = 0, goal_policy: str = ''
                   ) -> Attack.Request:
    """Attack.Request for a scene's objects, start and goal ('' policy: the server's)."""
    if scene.start is None or scene.goal is None:
        raise SceneError(f'scene {scene.name!r} needs a start and a goal to attack')
    goal = goal_region_to_msg(scene.goal, scene.frame)
    req = attack_request_from_msgs(scene_to_msg(scene), goal, budget, method, box_size_m, seed,
                                   goal_policy)
    cloud = scene_cloud(scene.objects)
    if cloud is not None:
        req.cloud, req.cloud_resolution = cloud_msg(cloud[0], scene.frame), float(cloud[1])
    return req


def plan_request(robot: RobotModel, q_start: np.ndarray, goal: GoalRegion, frame: str,
                 planner_id: str, time_budget_s: float, seed: int = 0) -> Plan.Request:
    """Plan.Request from ``q_start`` (nq,) [rad] in the robot's joint order to ``goal``."""
    req = Plan.Request()
    req.start_state = JointState(name=list(robot.joint_names),
                                 position=[float(v) for v in q_start])
    req.goal_region = goal_region_to_msg(goal, frame)
    req.planner_id = planner_id
    req.time_budget_s = float(time_budget_s)
    req.seed = int(seed)
    return req


def obstacles_from_msgs(obstacles: list[ObstacleMsg], prefix: str | None = None
                        ) -> tuple[SceneObject, ...]:
    """The boxes of an Attack response; ``prefix`` renames them ``{prefix}_{i}``."""
    return tuple(make_box(o.id if prefix is None else f'{prefix}_{i}',
                          (o.pose.position.x, o.pose.position.y, o.pose.position.z),
                          tuple(o.size)) for i, o in enumerate(obstacles))


def attack_response_data(res: Attack.Response, round_trip_s: float | None = None) -> dict:
    """JSON-able answer of an Attack response; ``obstacles`` in the scene-file format."""
    data = {'error_code': res.error_code.val, 'status': code_name(res.error_code.val),
            'message': res.message, 'obstacles': objects_to_data(obstacles_from_msgs(
                res.obstacles)),
            'masses': [float(o.covered_mass) for o in res.obstacles],
            'total_mass': float(res.total_mass), 'compute_ms': round(res.compute_time_s * 1e3, 3),
            'goal_valid_fraction': (None if res.goal_valid_fraction < 0
                                    else float(res.goal_valid_fraction)),
            'solvable': ({'verdict': res.solvable, 'message': res.solvable_message}
                         if res.solvable else None)}
    if round_trip_s is not None:
        data['round_trip_ms'] = round(round_trip_s * 1e3, 3)
    return data


def box_markers(objects: tuple[SceneObject, ...] | list[SceneObject], frame: str, ns: str
                ) -> MarkerArray:
    """DELETEALL of namespace ``ns``, then one red cube per box object."""
    markers = MarkerArray(markers=[Marker(ns=ns, action=Marker.DELETEALL)])
    for i, obj in enumerate(objects):
        shape = obj.shapes[0]
        marker = Marker(ns=ns, id=i, type=Marker.CUBE, action=Marker.ADD,
                        pose=pose_to_msg(shape.pose))
        marker.header.frame_id = frame
        marker.scale.x, marker.scale.y, marker.scale.z = (float(v) for v in shape.dims)
        marker.color.r, marker.color.g, marker.color.b, marker.color.a = 0.9, 0.1, 0.1, 0.7
        markers.markers.append(marker)
    return markers
