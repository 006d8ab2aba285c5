"""Field readers shared by the MotionBenchMaker scene and request importers.

Each reader names the file and field of whatever is malformed (``SceneError``). MoveIt's YAML
comes in two flavours and both are read: lists (``position: [x, y, z]``, robowflex) and
mappings (``position: {x: .., y: .., z: ..}``, the ROS message layout).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.pose import Pose, SceneError, finite_array
from advocc_ros.model.shapes import Shape

PRIMITIVES = {'box': 'box', 'sphere': 'sphere', 'cylinder': 'cylinder',
              1: 'box', 2: 'sphere', 3: 'cylinder'}
PRIMITIVE_DIMS = {'box': 3, 'sphere': 1, 'cylinder': 2}
WORLD_FRAMES = ('', 'world', '/world')
ADD_OPERATIONS = (None, 0, 2, 'add', 'append', 'ADD', 'APPEND')


def as_mapping(data: Any, where: str) -> dict:
    """``data`` if it is a mapping, else ``SceneError`` naming ``where``."""
    if not isinstance(data, dict):
        raise SceneError(f'{where}: expected a mapping, got {type(data).__name__}')
    return data


def as_list(data: Any, where: str) -> list:
    """``data`` if it is a list (``None``: empty), else ``SceneError`` naming ``where``."""
    if data is None:
        return []
    if not isinstance(data, list):
        raise SceneError(f'{where}: expected a list, got {type(data).__name__}')
    return data


def numbers(data: Any, where: str, keys: str) -> np.ndarray:
    """A vector from ``[a, b, ...]`` or ``{a: .., b: ..}`` (missing dict keys are an error)."""
    if isinstance(data, dict):
        missing = [k for k in keys if k not in data]
        if missing:
            raise SceneError(f'{where}: missing {missing}')
        data = [data[k] for k in keys]
    if not isinstance(data, (list, tuple)) or len(data) != len(keys):
        raise SceneError(f'{where}: expected {len(keys)} numbers ({",".join(keys)}), got '
                         f'{data!r}')
    return finite_array(data, where, len(keys))  # n: a nested list is not a number


def floats(data: Any, where: str) -> np.ndarray:
    """A list of finite numbers of any length."""
    if not isinstance(data, list):
        raise SceneError(f'{where}: expected a list of numbers, got {data!r}')
    return finite_array(data, where, n=len(data))


def pose_se3(data: Any, where: str) -> pin.SE3:
    """A ``geometry_msgs/Pose`` mapping (``None``: identity); the quaternion is normalised."""
    if data is None:
        return pin.SE3.Identity()
    data = as_mapping(data, where)
    pos = numbers(data.get('position', [0, 0, 0]), f'{where}.position', 'xyz')
    quat = numbers(data.get('orientation', [0, 0, 0, 1]), f'{where}.orientation', 'xyzw')
    norm = np.linalg.norm(quat)
    if norm < 1e-6:
        raise SceneError(f'{where}.orientation: zero quaternion')
    x, y, z, w = quat / norm
    return pin.SE3(pin.Quaternion(w, x, y, z).matrix(), pos)


def primitive_shape(prim: Any, where: str, pose: pin.SE3) -> Shape:
    """A ``shape_msgs/SolidPrimitive`` mapping (box, sphere, cylinder) placed at ``pose``."""
    prim = as_mapping(prim, where)
    raw = prim.get('type')
    key = raw.lower() if isinstance(raw, str) else raw
    kind = PRIMITIVES.get(key) if isinstance(key, (str, int)) else None  # a list: unhashable
    if kind is None:
        raise SceneError(f'{where}.type: expected box, sphere or cylinder (or 1, 2, 3), got '
                         f'{raw!r}')
    dims = prim.get('dimensions')
    if not isinstance(dims, list) or len(dims) != PRIMITIVE_DIMS[kind]:
        layout = {'box': '[x, y, z]', 'sphere': '[radius]', 'cylinder': '[height, radius]'}[kind]
        raise SceneError(f'{where}.dimensions: a {kind} needs {layout}, got {dims!r}')
    arr = floats(dims, f'{where}.dimensions')
    if not np.all(arr > 0):
        raise SceneError(f'{where}.dimensions: values must be > 0, got {dims!r}')
    return Shape(kind, tuple(arr.tolist()), Pose.from_se3(pose))


def base_frame(robot: RobotModel) -> str:
    """Name of the robot's root link (the frame our scenes are expressed in)."""
    return next(f.name for f in robot.model.frames if f.type == pin.FrameType.BODY)


def joint_state(data: Any, where: str, robot: RobotModel) -> dict[str, float]:
    """Every joint of a ``sensor_msgs/JointState`` mapping by name (fingers too: they lock the
    joints outside the planning group); every planned joint must be there."""
    data = as_mapping(data, where)
    names = as_list(data.get('name'), f'{where}.name')
    positions = as_list(data.get('position'), f'{where}.position')
    if not names:
        raise SceneError(f'{where}.name: no joint names')
    if not all(isinstance(n, str) for n in names):
        raise SceneError(f'{where}.name: expected joint names (strings), got {names!r}')
    values = list(floats(positions, f'{where}.position'))
    try:
        q = robot.q_from_names(names, values, where)
    except RobotError as exc:
        raise SceneError(str(exc)) from None
    state = {n: float(v) for n, v in zip(names, values)}
    state.update(zip(robot.joint_names, q.tolist()))
    return state


def virtual_joint(state: Any, where: str) -> pin.SE3:
    """``T_world_base`` from a ``multi_dof_joint_state`` (MoveIt's ``virtual_joint``), identity
    when there is none."""
    if not isinstance(state, dict) or state.get('multi_dof_joint_state') is None:
        return pin.SE3.Identity()
    mdof = as_mapping(state['multi_dof_joint_state'], f'{where}.multi_dof_joint_state')
    names = as_list(mdof.get('joint_names'), f'{where}.multi_dof_joint_state.joint_names')
    transforms = as_list(mdof.get('transforms'), f'{where}.multi_dof_joint_state.transforms')
    if len(names) != len(transforms):
        raise SceneError(f'{where}.multi_dof_joint_state: {len(names)} joint_names but '
                         f'{len(transforms)} transforms')
    if len(names) > 1:
        raise SceneError(f'{where}.multi_dof_joint_state: {len(names)} multi-DOF joints; only '
                         'a single virtual joint (world -> robot base) is supported')
    if not names:
        return pin.SE3.Identity()
    tf = as_mapping(transforms[0], f'{where}.multi_dof_joint_state.transforms[0]')
    return pose_se3({'position': tf.get('translation', [0, 0, 0]),
                     'orientation': tf.get('rotation', [0, 0, 0, 1])},
                    f'{where}.multi_dof_joint_state.transforms[0]')
