"""Seeded variations of a scene, the way MotionBenchMaker makes many problems from one family.

Each variation moves and resizes the scene's objects a little and keeps the task meaningful:
- *items* (single-shape objects) get a uniform planar offset (``±jitter_pos_m`` in x and y), a
  rotation about the vertical (``±jitter_yaw_rad``) and a relative size change per axis
  (``±jitter_size``); upright items keep their bottom where it was, so nothing sinks into or
  floats above its support;
- *rigid groups* (ids matching one ``rigid`` pattern, e.g. every ``shelf_*`` board and panel,
  and multi-shape objects) share one planar offset and are never resized, so a shelf stays a
  shelf;
- *fixed* objects (the table) never move;
- the *target* (ids matching ``target``) moves but keeps its size, and the goal region moves
  with it: the pre-grasp stays a pre-grasp of the object rather than of empty space.
A draw is rejected and drawn again when an object touches the robot at the start configuration
(that object alone is re-drawn) or when no collision-free IK solution inside the goal region is
found (the whole variation is re-drawn). Variation ``i`` depends only on ``(seed, i)``.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import logging
import pathlib

import numpy as np
import pinocchio as pin

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import Scene, SceneObject, save_yaml_atomic
from advocc_ros.model.shapes import Shape

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class VariationConfig:
    """How much a variation may differ from its scene, and how hard to try for a valid one."""

    jitter_pos_m: float = 0.02
    """Half-range of the uniform planar (x, y) offset of each item and rigid group [m]."""
    jitter_size: float = 0.1
    """Half-range of the relative size change of each item, per axis (0.1: ±10 %)."""
    jitter_yaw_rad: float = 0.1
    """Half-range of each item's rotation about the vertical axis through its centre [rad]."""
    fixed: tuple[str, ...] = ('table',)
    """Glob patterns of object ids that never move."""
    rigid: tuple[str, ...] = ('shelf_*', 'bin_*', 'cage_*')
    """Glob patterns; the objects matching one pattern move together and keep their size."""
    target: tuple[str, ...] = ('target*',)
    """Glob patterns of the object the goal region belongs to (moved, not resized)."""
    start_margin_m: float = 0.005
    """An object closer than this to the robot at the start configuration is re-drawn [m]."""
    max_object_draws: int = 20
    """Draws of one object before the whole variation is drawn again."""
    max_draws: int = 20
    """Draws of a whole variation before giving up with an error."""
    ik_attempts: int = 400
    """IK attempts (random seeds) to find one valid configuration inside the goal region."""

    def __post_init__(self):
        for name in ('jitter_pos_m', 'jitter_size', 'jitter_yaw_rad', 'start_margin_m'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f'{name}: expected a finite value >= 0, got {value!r}')
        if self.jitter_size >= 1:
            raise ValueError(f'jitter_size: expected < 1 (a relative change), got '
                             f'{self.jitter_size!r}')
        for name in ('max_object_draws', 'max_draws', 'ik_attempts'):
            if getattr(self, name) < 1:
                raise ValueError(f'{name}: expected >= 1, got {getattr(self, name)!r}')


@dataclasses.dataclass(frozen=True)
class Variation:
    """One accepted variation and what it took to find it."""

    scene: Scene
    index: int
    draws: int
    """Whole-variation draws (1: the first draw was valid)."""
    redrawn_objects: int
    """Objects re-drawn because they touched the robot at the start configuration."""


def _matches(obj_id: str, patterns: tuple[str, ...]) -> bool:
    return any(fnmatch.fnmatchcase(obj_id, p) for p in patterns)


def _planar_motion(dx: float, dy: float, yaw: float, pivot_m) -> pin.SE3:
    """Rotation by ``yaw`` about the vertical through ``pivot_m``, then a shift (dx, dy)."""
    R = pin.rpy.rpyToMatrix(0.0, 0.0, yaw)
    pivot = np.asarray(pivot_m, dtype=float)
    return pin.SE3(R, pivot - R @ pivot + np.array([dx, dy, 0.0]))


def _moved(shape: Shape, M: pin.SE3) -> Shape:
    return dataclasses.replace(shape, pose=Pose.from_se3(M * shape.pose.to_se3()))


def _resized(shape: Shape, scale: np.ndarray) -> Shape:
    """``shape`` with its dimensions scaled; an upright shape keeps its bottom height."""
    if shape.kind == 'mesh':
        return shape
    T = shape.pose.to_se3()
    if shape.kind == 'box':
        dims = tuple(float(d * s) for d, s in zip(shape.dims, scale))
        half_height_change = (dims[2] - shape.dims[2]) / 2
    elif shape.kind == 'cylinder':  # (height, radius)
        dims = (float(shape.dims[0] * scale[2]), float(shape.dims[1] * scale[0]))
        half_height_change = (dims[0] - shape.dims[0]) / 2
    else:  # sphere
        dims = (float(shape.dims[0] * scale[0]),)
        half_height_change = dims[0] - shape.dims[0]
    upright = abs(T.rotation[2, 2]) > 0.99 or shape.kind == 'sphere'
    pos = np.array(T.translation)
    if upright:
        pos[2] += half_height_change
    return dataclasses.replace(shape, dims=dims,
                               pose=Pose(tuple(pos.tolist()), shape.pose.quat_xyzw))


class _Drawer:
    """Draws one variation's objects with a given generator."""

    def __init__(self, scene: Scene, config: VariationConfig):
        self.scene, self.config = scene, config
        self.groups: dict[str, list[int]] = {}  # rigid pattern -> object indices
        for i, obj in enumerate(scene.objects):
            for pattern in config.rigid:
                if not _matches(obj.id, config.fixed + config.target) \
                        and fnmatch.fnmatchcase(obj.id, pattern):
                    self.groups.setdefault(pattern, []).append(i)
                    break

    def group_motion(self, rng: np.random.Generator) -> pin.SE3:
        j = self.config.jitter_pos_m
        return _planar_motion(rng.uniform(-j, j), rng.uniform(-j, j), 0.0, np.zeros(3))

    def item(self, obj: SceneObject, rng: np.random.Generator) -> tuple[SceneObject, pin.SE3]:
        """A jittered copy of a single-shape or multi-shape object, and its planar motion."""
        c = self.config
        is_target = _matches(obj.id, c.target)
        dx, dy = rng.uniform(-c.jitter_pos_m, c.jitter_pos_m, size=2)
        yaw = rng.uniform(-c.jitter_yaw_rad, c.jitter_yaw_rad)
        scale = 1.0 + rng.uniform(-c.jitter_size, c.jitter_size, size=3)
        if len(obj.shapes) > 1:  # a composite object moves as one body, like a rigid group
            yaw, pivot = 0.0, np.zeros(3)
        else:
            pivot = obj.shapes[0].pose.position_m
        M = _planar_motion(dx, dy, yaw, pivot)
        shapes = []
        for shape in obj.shapes:
            if len(obj.shapes) == 1 and not is_target:
                shape = _resized(shape, scale)
            shapes.append(_moved(shape, M))
        return SceneObject(obj.id, tuple(shapes)), M


def _goal_moved(goal: GoalRegion, M: pin.SE3) -> GoalRegion:
    return dataclasses.replace(goal, center=Pose.from_se3(M * goal.center.to_se3()))


def vary_scene(scene: Scene, index: int, seed: int,
               config: VariationConfig = VariationConfig()) -> Variation:
    """Variation ``index`` of ``scene`` under ``seed`` (see the module docstring).

    Raises ``SceneError`` if ``config.max_draws`` draws give no valid variation.
    """
    from advocc_ros.kinematics.ik import GoalSampler, start_configuration

    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    bare = CollisionWorld(robot)
    if not bare.is_valid(q_init):
        raise SceneError(f'{scene.name}: the start configuration is invalid (limits or '
                         'self-collision); nothing to vary')
    drawer = _Drawer(scene, config)
    redrawn = 0
    for draw in range(config.max_draws):
        rng = np.random.default_rng([seed, index, draw])
        objects, goal, redraws = _draw_objects(scene, drawer, config, bare, q_init, rng)
        redrawn += redraws
        if objects is None:
            log.debug('%s variation %d draw %d: an object keeps touching the robot at start',
                      scene.name, index, draw)
            continue
        candidate = dataclasses.replace(scene, objects=tuple(objects), goal=goal,
                                        name=f'{scene.name}_{index:04d}')
        world = CollisionWorld(robot, candidate.shapes)
        if not world.is_valid(q_init):
            continue
        if goal is not None:
            sampler = GoalSampler(robot, world.in_collision, goal, rng)
            if not any(sampler.attempt() is not None for _ in range(config.ik_attempts)):
                log.debug('%s variation %d draw %d: no valid IK solution in the goal region',
                          scene.name, index, draw)
                continue
        return Variation(candidate, index, draw + 1, redrawn)
    raise SceneError(f'{scene.name}: no valid variation {index} (seed {seed}) in '
                     f'{config.max_draws} draws; reduce the jitter')


def _draw_objects(scene: Scene, drawer: _Drawer, config: VariationConfig, bare: CollisionWorld,
                  q_init: np.ndarray, rng: np.random.Generator):
    """One draw of every movable object's pose (a rigid group moves together), each redrawn
    until it keeps ``config.start_margin_m`` from the robot at ``q_init``; the goal follows the
    target object. ``(objects, goal, redraws)``; objects is None when one found no clear pose
    in ``config.max_object_draws`` draws."""
    objects = list(scene.objects)
    goal = scene.goal
    redrawn = 0
    group_of = {i: pattern for pattern, members in drawer.groups.items() for i in members}
    for pattern, members in drawer.groups.items():
        for _ in range(config.max_object_draws):
            M = drawer.group_motion(rng)
            moved = [SceneObject(scene.objects[i].id, tuple(
                _moved(s, M) for s in scene.objects[i].shapes)) for i in members]
            if not any(bare.shape_collides(s, q_init, config.start_margin_m)
                       for o in moved for s in o.shapes):
                break
            redrawn += 1
        else:
            return None, goal, redrawn
        for i, obj in zip(members, moved):
            objects[i] = obj
    for i, obj in enumerate(scene.objects):
        if i in group_of or _matches(obj.id, config.fixed):
            continue
        for _ in range(config.max_object_draws):
            new, M = drawer.item(obj, rng)
            if not any(bare.shape_collides(s, q_init, config.start_margin_m)
                       for s in new.shapes):
                break
            redrawn += 1
        else:
            return None, goal, redrawn
        objects[i] = new
        if goal is not None and _matches(obj.id, config.target):
            goal = _goal_moved(scene.goal, M)
    return objects, goal, redrawn


def write_variation(scene: Scene, index: int, seed: int, out_dir: str | pathlib.Path,
                    config: VariationConfig = VariationConfig()) -> tuple[pathlib.Path, Variation]:
    """Variation ``index`` of ``scene`` as a scene file ``out_dir/<name>.yaml`` (atomic),
    its description saying where it comes from."""
    var = vary_scene(scene, index, seed, config)
    data = var.scene.to_data()
    data['description'] = (f'variation {index} of {scene.name} (seed {seed}, jitter pos '
                           f'{config.jitter_pos_m} m, size {config.jitter_size}, yaw '
                           f'{config.jitter_yaw_rad} rad)')
    path = pathlib.Path(out_dir) / f'{var.scene.name}.yaml'
    save_yaml_atomic(path, data)
    return path, var
