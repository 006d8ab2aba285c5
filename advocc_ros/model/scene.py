"""Scenes: collision objects, start configuration and goal region, and their YAML files.

Everything is expressed in the robot base frame, in metres; quaternions are ``[x, y, z, w]`` as in
ROS messages. A scene file is our own YAML (see ``config/scenes/table_pick.yaml``); the loader
names the file and the field of anything malformed.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib
from typing import Any

import numpy as np
import yaml

from advocc_ros.limits import MAX_FILE_BYTES, MAX_OBJECTS, yaml_flow_depth, yaml_size
from advocc_ros.model.cloud import cloud_shape_from_data, cloud_to_data
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.robot import RobotSpec, with_state
from advocc_ros.model.shapes import (SHAPES, Pose, SceneError, Shape, finite_array,
                                     mesh_shape_from_data)


@dataclasses.dataclass(frozen=True)
class SceneObject:
    """A named collision object made of one or more shapes (like a MoveIt CollisionObject)."""

    id: str
    shapes: tuple[Shape, ...]


def task_hash(robot_hash: str, objects, goal: GoalRegion, *extra) -> str:
    """A hash of what a task's answers depend on: robot, object shapes, goal region, and the
    caller's ``extra`` (start, seed, sample count). Shape fingerprints, not object data: a sensed
    cloud's points would be serialized on every call."""
    shapes = [[o.id, [s.fingerprint() for s in o.shapes]] for o in objects]
    text = json.dumps([robot_hash, shapes, goal.to_data(), list(extra)], sort_keys=True,
                      default=float)
    return hashlib.sha256(text.encode()).hexdigest()


def make_box(obj_id: str, center_m, size_m) -> SceneObject:
    """Axis-aligned box object centred at ``center_m`` with edge lengths ``size_m``."""
    pose = Pose(tuple(float(v) for v in center_m))
    return SceneObject(obj_id, (Shape('box', tuple(float(v) for v in size_m), pose),))


@dataclasses.dataclass(frozen=True)
class Scene:
    """A planning task: static objects E, start configuration and goal region."""

    objects: tuple[SceneObject, ...] = ()
    start: dict[str, float] | None = None
    """Start joint values by joint name (``None``: no start given). Values of joints outside the
    planning group (fingers) lock those joints: ``robot`` is derived from them (docs/design.md)."""
    goal: GoalRegion | None = None
    robot: RobotSpec = RobotSpec()
    name: str = 'scene'
    frame: str | None = None
    """Frame of every pose in the scene (``None``: the robot's ``base_frame``)."""

    def __post_init__(self):
        object.__setattr__(self, 'robot', with_state(self.robot, self.start))
        if self.frame is None:
            object.__setattr__(self, 'frame', self.robot.base_frame)

    @property
    def shapes(self) -> list[Shape]:
        return [s for o in self.objects for s in o.shapes]

    def with_objects(self, extra: tuple[SceneObject, ...] | list[SceneObject]) -> 'Scene':
        ids = {o.id for o in self.objects}
        clash = [o.id for o in extra if o.id in ids]
        if clash:
            raise SceneError(f'object ids already in the scene: {clash}')
        return dataclasses.replace(self, objects=self.objects + tuple(extra))

    def without_objects(self) -> 'Scene':
        return dataclasses.replace(self, objects=())

    def objects_hash(self) -> str:
        """Hash of the geometry only (not start/goal): what a scene-conditioned heatmap saw."""
        data = sorted([o.id, [s.fingerprint() for s in o.shapes]] for o in self.objects)
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]

    def to_data(self) -> dict:
        data: dict[str, Any] = {'name': self.name, 'frame': self.frame,
                                'robot': self.robot.to_dict()}
        if self.start is not None:
            data['start'] = {k: float(v) for k, v in self.start.items()}
        if self.goal is not None:
            data['goal'] = self.goal.to_data()
        data['objects'] = objects_to_data(self.objects)
        return data


def objects_to_data(objects) -> list[dict]:
    out = []
    for obj in objects:
        for k, shape in enumerate(obj.shapes):
            entry: dict[str, Any] = {'id': obj.id if len(obj.shapes) == 1 else f'{obj.id}#{k}',
                                     'type': shape.kind, 'pose': shape.pose.to_data()}
            if shape.kind == 'box':
                entry['size'] = [float(v) for v in shape.dims]
            elif shape.kind == 'sphere':
                entry['radius'] = float(shape.dims[0])
            elif shape.kind == 'cylinder':
                entry['height'], entry['radius'] = float(shape.dims[0]), float(shape.dims[1])
            elif shape.kind == 'cloud':
                entry.update(cloud_to_data(shape))
            else:
                entry['vertices'] = np.asarray(shape.vertices).tolist()
                entry['faces'] = np.asarray(shape.faces).tolist()
            out.append(entry)
    return out


def _shape_from_data(entry: dict, where: str, base_dir: pathlib.Path | None) -> Shape:
    kind = entry.get('type')
    if kind not in SHAPES:
        raise SceneError(f'{where}.type: expected one of {list(SHAPES)}, got {kind!r}')
    allowed = {'id', 'type', 'pose', 'size', 'radius', 'height', 'file', 'scale', 'vertices',
               'faces', 'resolution', 'points'}
    unknown = set(entry) - allowed
    if unknown:
        raise SceneError(f'{where}: unknown field(s) {sorted(unknown)}')
    pose = Pose.from_data(entry.get('pose'), f'{where}.pose')
    if kind == 'box':
        if 'size' not in entry:
            raise SceneError(f'{where}.size: missing (box edge lengths [x, y, z])')
        dims = finite_array(entry['size'], f'{where}.size', 3, positive=True)
        return Shape('box', tuple(dims.tolist()), pose)
    if kind == 'sphere':
        if 'radius' not in entry:
            raise SceneError(f'{where}.radius: missing')
        radius = finite_array([entry['radius']], f'{where}.radius', 1, positive=True)
        return Shape('sphere', tuple(radius.tolist()), pose)
    if kind == 'cylinder':
        for key in ('height', 'radius'):
            if key not in entry:
                raise SceneError(f'{where}.{key}: missing')
        h = finite_array([entry['height']], f'{where}.height', 1, positive=True)[0]
        r = finite_array([entry['radius']], f'{where}.radius', 1, positive=True)[0]
        return Shape('cylinder', (float(h), float(r)), pose)
    if kind == 'cloud':
        return cloud_shape_from_data(entry, where, base_dir, pose)
    return mesh_shape_from_data(entry, where, base_dir, pose)


def objects_from_data(entries: Any, where: str, base_dir: pathlib.Path | None = None
                      ) -> tuple[SceneObject, ...]:
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise SceneError(f'{where}: expected a list of objects')
    if len(entries) > MAX_OBJECTS:
        raise SceneError(f'{where}: {len(entries)} objects, limit {MAX_OBJECTS}')
    objects, seen = [], set()
    for i, entry in enumerate(entries):
        w = f'{where}[{i}]'
        if not isinstance(entry, dict):
            raise SceneError(f'{w}: expected a mapping')
        obj_id = entry.get('id', f'object_{i}')
        if not isinstance(obj_id, str) or not obj_id:
            raise SceneError(f'{w}.id: expected a non-empty string, got {obj_id!r}')
        if obj_id in seen:
            raise SceneError(f'{w}.id: duplicate id {obj_id!r}')
        seen.add(obj_id)
        objects.append(SceneObject(obj_id, (_shape_from_data(entry, w, base_dir),)))
    return tuple(objects)


def _start_from_data(data: Any, where: str) -> dict[str, float]:
    if not isinstance(data, dict) or not data:
        raise SceneError(f'{where}: expected a mapping joint_name: position')
    out = {}
    for name, value in data.items():
        out[str(name)] = float(finite_array([value], f'{where}.{name}', 1)[0])
    return out


_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
"""The safe constructor either way: plain data only, no Python tags."""


def read_yaml(path: str | pathlib.Path) -> Any:
    """A YAML file through the safe loader (libyaml's parser when present: seconds, not
    minutes, for a file at ``MAX_FILE_BYTES``), with errors that name the file.

    Bounded: files over ``MAX_FILE_BYTES``, documents whose aliases expand past
    ``MAX_YAML_NODES`` values, recursive aliases and absurd nesting are refused here, before
    any parser turns them into arrays.
    """
    path = pathlib.Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise SceneError(f'{path}: {size} bytes, limit {MAX_FILE_BYTES} (MAX_FILE_BYTES)')
        raw = path.read_bytes()
        text = raw.decode()
        yaml_flow_depth(raw)
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f'{path}: cannot read ({exc})') from exc
    except ValueError as exc:
        raise SceneError(f'{path}: {exc}') from None
    loader = _YAML_LOADER(text)  # what yaml.safe_load does, with libyaml's parser
    try:
        data = loader.get_single_data()
    except yaml.YAMLError as exc:
        raise SceneError(f'{path}: malformed YAML ({exc})') from exc
    except RecursionError:
        raise SceneError(f'{path}: malformed YAML (nested too deeply)') from None
    except (ValueError, TypeError, AttributeError) as exc:  # PyYAML's constructors on odd
        # scalars, e.g. a !!timestamp that is not one (AttributeError on a failed match)
        raise SceneError(f'{path}: malformed YAML (a tagged or complex value that cannot be '
                         f'built: {type(exc).__name__}: {exc})') from None
    finally:
        loader.dispose()
    try:
        yaml_size(data)
    except ValueError as exc:
        raise SceneError(f'{path}: {exc}') from None
    return data


def scene_from_data(data: Any, where: str, base_dir: pathlib.Path | None = None) -> Scene:
    if not isinstance(data, dict):
        raise SceneError(f'{where}: expected a mapping at the top level')
    known = {'name', 'frame', 'robot', 'start', 'goal', 'objects', 'description'}
    unknown = set(data) - known
    if unknown:
        raise SceneError(f'{where}: unknown field(s) {sorted(unknown)}; known: {sorted(known)}')
    try:
        robot = RobotSpec.from_dict(data.get('robot', {}), f'{where}.robot')
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    return Scene(
        objects=objects_from_data(data.get('objects'), f'{where}.objects', base_dir),
        start=_start_from_data(data['start'], f'{where}.start') if 'start' in data else None,
        goal=GoalRegion.from_data(data['goal'], f'{where}.goal', robot.ee_link)
        if 'goal' in data else None,
        robot=robot,
        name=str(data.get('name', pathlib.Path(where).stem)),
        frame=str(data['frame']) if 'frame' in data else None)


def load_scene(path: str | pathlib.Path) -> Scene:
    """Load one of our scene YAML files; errors name the file and the field."""
    path = pathlib.Path(path)
    return scene_from_data(read_yaml(path), str(path), path.parent)


def referenced_files(path: str | pathlib.Path) -> list[pathlib.Path]:
    """Files a scene file's objects read (mesh and cloud ``file`` fields), resolved against
    the scene's folder: what a node must confine before loading the scene."""
    path = pathlib.Path(path)
    data = read_yaml(path)
    objects = data.get('objects') if isinstance(data, dict) else None
    out = []
    for entry in objects if isinstance(objects, list) else []:
        if isinstance(entry, dict) and 'file' in entry:
            file = pathlib.Path(str(entry['file']))
            out.append(file if file.is_absolute() else path.parent / file)
    return out


def save_yaml_atomic(path: str | pathlib.Path, data: Any) -> None:
    """Write YAML so that a crash leaves either the old or the new file, never half of one."""
    from advocc_ros.fileio import atomic_write_text
    atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))


class Operation:
    """Collision-object operations, with the values of moveit_msgs/CollisionObject."""

    ADD, REMOVE, APPEND, MOVE = 0, 1, 2, 3


def apply_operation(objects: dict[str, SceneObject], operation: int, obj: SceneObject,
                    new_pose: Pose | None = None) -> dict[str, SceneObject]:
    """A new id -> object mapping after one MoveIt-style collision-object operation.

    ADD replaces an object of the same id; REMOVE with an empty id clears all objects; APPEND
    adds shapes to an object (creating it if missing); MOVE re-poses every shape of the object
    by the motion that takes its first shape to ``new_pose`` (shapes keep their relative poses).
    """
    objects = dict(objects)
    if operation == Operation.ADD:
        objects[obj.id] = obj
    elif operation == Operation.REMOVE:
        if not obj.id:
            objects.clear()
        elif obj.id not in objects:
            raise SceneError(f'REMOVE: no object with id {obj.id!r}')
        else:
            del objects[obj.id]
    elif operation == Operation.APPEND:
        old = objects.get(obj.id)
        objects[obj.id] = SceneObject(obj.id, (old.shapes if old else ()) + obj.shapes)
    elif operation == Operation.MOVE:
        if obj.id not in objects:
            raise SceneError(f'MOVE: no object with id {obj.id!r}')
        if new_pose is None:
            raise SceneError('MOVE: a new pose is needed')
        old = objects[obj.id]
        delta = new_pose.to_se3() * old.shapes[0].pose.to_se3().inverse()
        objects[obj.id] = SceneObject(obj.id, tuple(
            dataclasses.replace(s, pose=Pose.from_se3(delta * s.pose.to_se3()))
            for s in old.shapes))
    else:
        raise SceneError(f'unknown collision-object operation {operation}')
    return objects
