"""Robot model: kinematics (pinocchio), collision geometry (coal) and link solids.

The arm is reduced to its planning group: every joint outside the group (the Panda's fingers) is
locked with ``pinocchio.buildReducedModel``, so ``q`` is always the arm configuration (7 values
for the Panda) and nothing downstream has to slice it. Locked joints take the values of the robot
state that comes with the task (``RobotSpec.locked``, set by ``with_state``), clipped into their
limits; without one, the SRDF group state. Mimic joints follow their leader (URDF ``<mimic>``).
The locked values are part of the robot's identity (``RobotModel.hash``).

Immutable model objects live here; per-thread scratch (``pinocchio.Data``, ``GeometryData``)
is created by ``RobotModel.create_data`` / ``CollisionWorld``, the way pinocchio separates
``model`` from ``model.createData()``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import logging
import pathlib
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING

import coal
import numpy as np
import pinocchio as pin

from advocc_ros.model.coal_state import exact_boxes
from advocc_ros.model.motion_bound import MotionBound, MotionBoundError, motion_bound

if TYPE_CHECKING:  # trimesh (0.3 s to import) loads only where link solids are voxelized
    import trimesh

log = logging.getLogger(__name__)

exact_boxes()  # coal's one process-wide setting, fixed before any robot geometry exists


class RobotError(ValueError):
    """A robot description that cannot be loaded or a request that does not fit the robot."""


def example_robot_data_share() -> pathlib.Path:
    """Directory that holds ``example-robot-data/robots`` (installed by the PyPI package)."""
    import site

    for base in site.getsitepackages():
        share = pathlib.Path(base) / 'cmeel.prefix' / 'share'
        if (share / 'example-robot-data' / 'robots').is_dir():
            return share
    raise RobotError('example-robot-data is not installed (pip install example-robot-data)')


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """Where a robot comes from and which part of it is planned for."""

    urdf: str = 'example-robot-data://panda_description/urdf/panda.urdf'
    """URDF path; ``example-robot-data://`` resolves inside the example-robot-data package."""
    srdf: str = 'example-robot-data://panda_description/srdf/panda.srdf'
    """SRDF path: disabled collision pairs, planning group and reference joint values."""
    group: str = 'arm'
    """SRDF group whose joints are planned; other joints are locked. Empty: every joint."""
    ee_link: str = 'panda_hand'
    """End-effector link for goal regions, manipulability and corridors."""
    base_frame: str = 'panda_link0'
    """Frame of the robot's base: poses of scenes, requests and messages are in it."""
    moveit_group: str = 'panda_arm'
    """The planning group's name in the robot's MoveIt configuration (exported requests)."""
    group_state: str = 'default'
    """SRDF group state giving the values of locked joints (missing ones: 0)."""
    locked: tuple[tuple[str, float], ...] = ()
    """``(joint, value)`` pairs of the task's robot state for joints outside the group [rad or
    m]; they override the SRDF group state. Set it with ``with_state``."""

    @classmethod
    def from_dict(cls, data: dict, where: str = 'robot') -> 'RobotSpec':
        if not isinstance(data, dict):
            raise RobotError(f'{where}: expected a mapping, got {type(data).__name__}')
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - fields
        if unknown:
            raise RobotError(f'{where}: unknown field(s) {sorted(unknown)}; '
                             f'known: {sorted(fields)}')
        data = dict(data)
        locked = data.pop('locked', None) or {}
        if not isinstance(locked, dict):
            raise RobotError(f'{where}.locked: expected a mapping joint: value, got {locked!r}')
        for key, value in data.items():
            if not isinstance(value, str):
                raise RobotError(f'{where}.{key}: expected a string, got {value!r}')
        pairs = []
        for name, value in locked.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not np.isfinite(value):
                raise RobotError(f'{where}.locked.{name}: expected a finite number, got {value!r}')
            pairs.append((str(name), float(value)))
        return cls(**data, locked=tuple(sorted(pairs)))

    def to_dict(self) -> dict:
        """Plain data for YAML (``locked`` as a mapping, left out when empty)."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != 'locked'}
        if self.locked:
            data['locked'] = {name: float(value) for name, value in self.locked}
        return data


def resolve_path(path: str) -> pathlib.Path:
    prefix = 'example-robot-data://'
    if path.startswith(prefix):
        return example_robot_data_share() / 'example-robot-data' / 'robots' / path[len(prefix):]
    return pathlib.Path(path).expanduser()


def _srdf_group(srdf: ET.Element, name: str) -> list[str]:
    """Joint names of an SRDF group, following nested groups and chains are not supported."""
    for group in srdf.iter('group'):
        if group.get('name') == name:
            joints = [j.get('name') for j in group.findall('joint')]
            for sub in group.findall('group'):
                joints += _srdf_group(srdf, sub.get('name'))
            return joints
    return []


def _srdf_state(srdf: ET.Element, name: str) -> dict[str, float]:
    for state in srdf.iter('group_state'):
        if state.get('name') == name:
            return {j.get('name'): float(j.get('value')) for j in state.findall('joint')}
    return {}


@functools.lru_cache(maxsize=16)
def _srdf_group_cached(path: str, mtime: float, group: str) -> frozenset[str]:
    try:
        return frozenset(_srdf_group(ET.parse(path).getroot(), group))
    except (OSError, ET.ParseError):
        return frozenset()


def with_state(spec: RobotSpec, joint_values: dict[str, float] | None) -> RobotSpec:
    """``spec`` whose locked joints take their values from a task's robot state.

    Only joints outside the planning group are kept (the arm's own values are the start, not the
    robot); a state that names none of them leaves ``spec`` unchanged. Values are clipped into
    the joint limits (with a warning) and mimic joints re-derived when the model is built.
    """
    if not joint_values or not spec.group:
        return spec
    srdf = resolve_path(spec.srdf)
    try:
        mtime = srdf.stat().st_mtime
    except OSError:
        return spec  # the model load reports the missing SRDF
    group = _srdf_group_cached(str(srdf), mtime, spec.group)
    if not group:
        return spec
    pairs = {name: float(value) for name, value in joint_values.items() if name not in group}
    if not pairs:
        return spec
    return dataclasses.replace(spec, locked=tuple(sorted(pairs.items())))


def _urdf_mimics(urdf: pathlib.Path) -> dict[str, tuple[str, float, float]]:
    """``follower -> (leader, multiplier, offset)`` from the URDF's ``<mimic>`` tags."""
    out = {}
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as exc:
        raise RobotError(f'{urdf}: not valid XML ({exc})') from exc
    for joint in root.iter('joint'):
        mimic = joint.find('mimic')
        if mimic is not None and mimic.get('joint'):
            out[joint.get('name')] = (mimic.get('joint'), float(mimic.get('multiplier', 1.0)),
                                      float(mimic.get('offset', 0.0)))
    return out


def _resolve_locked(full: pin.Model, q_ref: np.ndarray, lock_ids: list[int],
                    state: dict[str, float], mimics: dict, warn: bool) -> np.ndarray:
    """``q_ref`` with the locked joints set from ``state`` (clipped), then mimic joints."""
    q_ref = q_ref.copy()
    locked = {full.names[j] for j in lock_ids}
    for name, value in state.items():
        if name not in locked or full.joints[full.getJointId(name)].nq != 1:
            continue
        idx = full.joints[full.getJointId(name)].idx_q
        lo, hi = full.lowerPositionLimit[idx], full.upperPositionLimit[idx]
        clipped = float(np.clip(value, lo, hi))
        if warn and clipped != value:
            log.warning('locked joint %s: the robot state gives %.6g, outside its limits '
                        '[%.6g, %.6g]; clipped to %.6g', name, value, lo, hi, clipped)
        q_ref[idx] = clipped
    for follower, (leader, mult, offset) in mimics.items():
        if follower in locked and leader in locked and full.existJointName(leader):
            value = mult * q_ref[full.joints[full.getJointId(leader)].idx_q] + offset
            idx = full.joints[full.getJointId(follower)].idx_q
            q_ref[idx] = np.clip(value, full.lowerPositionLimit[idx],
                                 full.upperPositionLimit[idx])
    return q_ref


def _geometry_trimesh(geom: pin.GeometryObject) -> trimesh.Trimesh:
    """Solid of one collision geometry, in the geometry's own frame."""
    import trimesh
    shape = geom.geometry
    if isinstance(shape, coal.Box):
        return trimesh.creation.box(extents=2.0 * np.asarray(shape.halfSide))
    if isinstance(shape, coal.Sphere):
        return trimesh.creation.icosphere(subdivisions=2, radius=shape.radius)
    if isinstance(shape, coal.Cylinder):
        return trimesh.creation.cylinder(radius=shape.radius, height=2.0 * shape.halfLength)
    if isinstance(shape, coal.Capsule):
        return trimesh.creation.capsule(radius=shape.radius, height=2.0 * shape.halfLength)
    if geom.meshPath and pathlib.Path(geom.meshPath).is_file():
        mesh = trimesh.load_mesh(geom.meshPath, force='mesh')
        mesh.apply_scale(np.asarray(geom.meshScale))
        return mesh
    raise RobotError(f'collision geometry {geom.name!r}: unsupported shape {type(shape).__name__}')


def _load_full(spec: RobotSpec):
    """``spec``'s URDF and SRDF paths, the SRDF's XML root, and the full pinocchio model with
    its collision geometry; ``RobotError`` for a missing or unreadable file."""
    urdf = resolve_path(spec.urdf)
    srdf = resolve_path(spec.srdf)
    for label, path in (('URDF', urdf), ('SRDF', srdf)):
        if not path.is_file():
            raise RobotError(f'{label} not found: {path}')
    try:
        srdf_xml = ET.parse(srdf).getroot()
    except ET.ParseError as exc:
        raise RobotError(f'{srdf}: not valid XML ({exc})') from exc
    package_dirs = [str(example_robot_data_share())]
    try:
        full = pin.buildModelFromUrdf(str(urdf))
        full_geom = pin.buildGeomFromUrdf(
            full, str(urdf), pin.GeometryType.COLLISION, package_dirs=package_dirs)
    except (RuntimeError, ValueError) as exc:
        raise RobotError(f'{urdf}: pinocchio could not load it ({exc})') from exc
    return urdf, srdf, srdf_xml, full, full_geom


def _locked_joints(spec: RobotSpec, urdf: pathlib.Path, srdf: pathlib.Path,
                   srdf_xml: ET.Element, full: pin.Model):
    """The joints outside ``spec``'s planning group and the values they are held at:
    ``(lock_ids, q_default, q_ref)``, full configurations with the SRDF's group state
    (``q_default``) and with ``spec.locked`` on top (``q_ref``), mimic joints derived."""
    group = _srdf_group(srdf_xml, spec.group) if spec.group else list(full.names[1:])
    if not group:
        raise RobotError(f'{srdf}: no group named {spec.group!r} (use group: "" to plan '
                         'for every joint)')
    state = _srdf_state(srdf_xml, spec.group_state)
    lock_ids, q_srdf = [], pin.neutral(full)
    for jid in range(1, full.njoints):
        name = full.names[jid]
        if name not in group:
            lock_ids.append(jid)
        if name in state and full.joints[jid].nq == 1:
            q_srdf[full.joints[jid].idx_q] = state[name]
    mimics = _urdf_mimics(urdf)
    q_default = _resolve_locked(full, q_srdf, lock_ids, {}, mimics, warn=False)
    q_ref = _resolve_locked(full, q_srdf, lock_ids, dict(spec.locked), mimics, warn=True)
    missing = [j for j in group if not full.existJointName(j)]
    if missing:
        raise RobotError(f'{srdf}: group {spec.group!r} names joints not in the URDF: '
                         f'{missing}')
    return lock_ids, q_default, q_ref


class RobotModel:
    """Reduced arm model with collision geometry; immutable after construction."""

    def __init__(self, spec: RobotSpec = RobotSpec()):
        self.spec = spec
        urdf, srdf, srdf_xml, full, full_geom = _load_full(spec)
        lock_ids, q_default, q_ref = _locked_joints(spec, urdf, srdf, srdf_xml, full)
        self.locked_values: dict[str, float] = {
            full.names[j]: float(q_ref[full.joints[j].idx_q])
            for j in lock_ids if full.joints[j].nq == 1}
        """Values the locked joints are held at, by joint name."""
        self.model, self.collision_model = pin.buildReducedModel(full, full_geom, lock_ids, q_ref)
        if self.model.nq != self.model.nv:
            raise RobotError('continuous/multi-DoF joints in the planning group are not supported')
        self.joint_names: tuple[str, ...] = tuple(self.model.names[1:])
        self.lower = np.array(self.model.lowerPositionLimit, dtype=float)
        self.upper = np.array(self.model.upperPositionLimit, dtype=float)
        if not np.all(np.isfinite(self.lower) & np.isfinite(self.upper)):
            raise RobotError('every planned joint needs finite position limits')
        if not self.model.existFrame(spec.ee_link):
            raise RobotError(f'end-effector link {spec.ee_link!r} is not in {urdf}')
        self.ee_frame = self.model.getFrameId(spec.ee_link)

        self.collision_model.addAllCollisionPairs()
        pin.removeCollisionPairs(self.model, self.collision_model, str(srdf))
        # Pairs on the same joint never move relative to each other (fingers locked on the hand).
        self.self_pairs = [
            (p.first, p.second) for p in self.collision_model.collisionPairs
            if self.collision_model.geometryObjects[p.first].parentJoint
            != self.collision_model.geometryObjects[p.second].parentJoint]
        self.link_names: tuple[str, ...] = tuple(
            g.name for g in self.collision_model.geometryObjects)
        try:
            self.motion_bound: MotionBound = motion_bound(self.model, self.collision_model)
            """How far collision geometry moves per rad of joint motion (continuous checks)."""
        except MotionBoundError as exc:
            raise RobotError(f'{urdf}: {exc}') from exc
        identity = urdf.read_bytes() + srdf.read_bytes() + repr(
            (spec.group, spec.ee_link, spec.group_state)).encode()
        if not np.allclose(q_ref, q_default, rtol=0.0, atol=1e-9):
            # A state that moves a locked joint makes another robot: a heatmap built with
            # closed fingers must not be used with open ones.
            identity += repr(sorted((k, round(v, 9)) for k, v in self.locked_values.items())
                             ).encode()
        self.hash = hashlib.sha256(identity).hexdigest()[:16]
        log.debug('robot %s: %d joints, %d geometries, %d self pairs', urdf.name,
                  self.model.nq, len(self.link_names), len(self.self_pairs))

    @property
    def nq(self) -> int:
        return self.model.nq

    def create_data(self) -> pin.Data:
        return self.model.createData()

    def check_q(self, q: np.ndarray, what: str = 'q') -> np.ndarray:
        """Return ``q`` as a float array of the right size, or raise a clear error."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise RobotError(f'{what}: expected {self.nq} joint values, got shape {q.shape}')
        if not np.all(np.isfinite(q)):
            raise RobotError(f'{what}: non-finite joint values {q.tolist()}')
        return q

    def q_from_names(self, names: list[str], positions: list[float], what: str = 'joint state'
                     ) -> np.ndarray:
        """Arm configuration from a (name, position) joint state; extra joints are ignored."""
        if len(names) != len(positions):
            raise RobotError(f'{what}: {len(names)} names but {len(positions)} positions')
        lookup = dict(zip(names, positions))
        missing = [j for j in self.joint_names if j not in lookup]
        if missing:
            raise RobotError(f'{what}: missing joints {missing} (robot joints: '
                             f'{list(self.joint_names)})')
        return self.check_q(np.array([lookup[j] for j in self.joint_names]), what)

    def within_limits(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.lower - 1e-9) and np.all(q <= self.upper + 1e-9))

    def sample_q(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` configurations uniform within joint limits, shape (n, nq)."""
        return rng.uniform(self.lower, self.upper, size=(n, self.nq))

    def ee_pose(self, q: np.ndarray, data: pin.Data | None = None, link: str | None = None,
                tool: pin.SE3 | None = None) -> pin.SE3:
        """``T_base_ee`` of the end-effector link at ``q``; of ``link`` instead when given, and
        times ``tool`` (``T_link_tool``, a goal's tool offset) when given: the tool pose a goal
        region judges. The one tool-pose function (the attack, the witness, the IK)."""
        data = data or self.create_data()
        pin.framesForwardKinematics(self.model, data, q)
        T = data.oMf[self.ee_frame if link is None else self.model.getFrameId(link)]
        return T * tool if tool is not None else T.copy()

    def ee_jacobian(self, q: np.ndarray, data: pin.Data | None = None) -> np.ndarray:
        """6 x nq geometric Jacobian of the end-effector, in the base-aligned local frame."""
        data = data or self.create_data()
        jac = pin.computeFrameJacobian(self.model, data, q, self.ee_frame,
                                       pin.LOCAL_WORLD_ALIGNED)
        return np.asarray(jac).reshape(6, self.nq)  # eigenpy returns (6,) when nq == 1

    def manipulability(self, q: np.ndarray, data: pin.Data | None = None) -> float:
        """Yoshikawa index ``sqrt(det(J J^T))`` of the 6 x nq end-effector Jacobian."""
        jac = self.ee_jacobian(q, data)
        return float(np.sqrt(max(np.linalg.det(jac @ jac.T), 0.0)))

    @functools.cached_property
    def link_meshes(self) -> tuple[trimesh.Trimesh, ...]:
        """Solid of each collision geometry in its own frame (used for voxelization)."""
        return tuple(_geometry_trimesh(g) for g in self.collision_model.geometryObjects)

    @functools.cached_property
    def link_bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (L, 3): each collision geometry's bounding box in its own frame [m] (coal's
        local AABB: the bounds of ``link_meshes`` without loading them)."""
        boxes = []
        for g in self.collision_model.geometryObjects:
            g.geometry.computeLocalAABB()
            boxes.append((np.asarray(g.geometry.aabb_local.min_),
                          np.asarray(g.geometry.aabb_local.max_)))
        return np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])


@functools.lru_cache(maxsize=4)
def load_robot(spec: RobotSpec = RobotSpec()) -> RobotModel:
    """Cached ``RobotModel`` (loading meshes takes ~0.1 s)."""
    return RobotModel(spec)
