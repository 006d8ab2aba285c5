"""Robot-versus-scene collision checking and clearance with coal, driven by pinocchio.

A ``CollisionWorld`` is one pinocchio ``GeometryModel`` holding the robot's collision geometry
(link meshes replaced by their convex hulls: GJK on a hull is ~10x faster than a BVH traversal
and the hull contains the mesh, so checks stay conservative) plus the scene's shapes attached to
the world. Its pairs are the SRDF-filtered self pairs and every (link, scene shape) pair, so one
``computeCollisions`` call checks a configuration entirely in C++.

Validity checks go through a broad phase (coal's dynamic AABB tree, driven by pinocchio's
``BroadPhaseManager``): only pairs whose world AABBs overlap reach GJK. An AABB contains its
geometry, so the verdict is the one the all-pairs loop gives (test/test_collision_exact.py
compares the two on 100,000 configurations per shipped scene), at ~5x the speed (table_pick:
60 -> 12 us).
GJK starts cold on every query (see ``no_warm_start``), so a verdict never depends on which
configuration was checked before; coal's one process-wide setting (how much it inflates boxes) is
fixed before any query by ``advocc_ros.model.coal_state``, so it never depends on what a process
checked first.

Model and data are apart, as in pinocchio: a ``CollisionWorld`` (geometry, pairs) is built once
per scene and never changes, so threads share it; its queries run on the calling thread's
``CollisionData`` (``create_data()``: pinocchio data, geometry data, broad-phase manager), made
on the thread's first query.
"""

from __future__ import annotations

import functools
import json
import threading
import warnings

import coal
import numpy as np
import pinocchio as pin

from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.cloud import cloud_octree
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.shapes import Shape
from advocc_ros.model.voxels import VoxelGrid, occupied_mask


def coal_geometry(shape: Shape) -> coal.CollisionGeometry:
    """coal geometry of a scene shape, in the shape's own frame."""
    if shape.kind == 'box':
        return coal.Box(*shape.dims)
    if shape.kind == 'sphere':
        return coal.Sphere(shape.dims[0])
    if shape.kind == 'cylinder':
        return coal.Cylinder(shape.dims[1], shape.dims[0])  # radius, length (height)
    if shape.kind == 'cloud':
        return cloud_octree(shape)
    # Meshes (e.g. a sensed reconstruction) may be concave: keep the triangles in a BVH.
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(shape.faces), len(shape.vertices))
    bvh.addVertices(np.asarray(shape.vertices, dtype=float))
    bvh.addTriangles(np.asarray(shape.faces, dtype=np.int64))
    bvh.endModel()
    return bvh


def convex_hull(mesh: coal.BVHModelBase) -> coal.Convex:
    """The convex hull of a link mesh, keeping its extreme vertices only (coal runs qhull).

    coal's ``buildConvexRepresentation`` keeps every mesh vertex, including those inside the
    hull's faces (UR5: 283 points for 96 extreme ones). coal's support function climbs the
    vertex graph from the previous query's vertex, and those flat points let it stop early:
    GJK's verdict then depended on the previous configuration (measured: 262 of 100,000 UR5
    configurations changed verdict when checked in reverse order, with warm starts on).
    Panda's meshes are already convex, so their hull is the same point set as before.
    """
    points = np.asarray(mesh.vertices(), dtype=float)
    hull = coal.Convex.convexHull(list(points), True, 'Qt')
    hull.computeLocalAABB()
    return hull


_HULLS: BoundedCache = BoundedCache('convex link hulls', 8)
"""Robot hash -> {geometry index: hull}."""


def _convex_robot_model(robot: RobotModel) -> pin.GeometryModel:
    """A copy of the robot's collision model with meshes replaced by their hulls (computed
    once per robot: qhull takes ~1 ms a link, more than the rest of a world's set-up)."""
    hulls = _HULLS.get_or_make(robot.hash, lambda: {
        i: convex_hull(geom.geometry)
        for i, geom in enumerate(robot.collision_model.geometryObjects)
        if isinstance(geom.geometry, coal.BVHModelBase)})
    geom_model = robot.collision_model.copy()
    for i, hull in hulls.items():
        geom_model.geometryObjects[i].geometry = hull
    return geom_model


class CollisionData:
    """One thread's scratch for queries on a ``CollisionWorld`` (``world.create_data()``)."""

    def __init__(self, world: 'CollisionWorld'):
        self.data = world.robot.create_data()
        self.geom_data = world.geom_model.createData()  # placements (no queries run on it)
        self.broad_data = world.geom_model.createData()
        no_warm_start(self.broad_data.collisionRequests)
        self.broad = pin.BroadPhaseManager_DynamicAABBTreeCollisionManager(
            world.model, world.geom_model, self.broad_data)
        self.pool: pin.BroadPhaseManagerPool_DynamicAABBTreeCollisionManager | None = None
        self.margin_pool: tuple[float, pin.GeometryPool] | None = None
        self.near_data: tuple[float, pin.GeometryData] | None = None
        self.dist_data: pin.GeometryData | None = None
        """Scratch of the world's distance model (made on first use; no reference back to the
        world: a cycle would keep every world's C++ data alive until the next garbage
        collection, measured as +30 MB over 40 attack requests in a node)."""


class CollisionWorld:
    """Validity (joint limits, self and scene collision) and clearance for one scene."""

    def __init__(self, robot: RobotModel, shapes: list[Shape] = ()):
        self.robot = robot
        self.model = robot.model
        self.geom_model = _convex_robot_model(robot)
        self.n_links = self.geom_model.ngeoms
        self.shapes = list(shapes)
        for i, shape in enumerate(self.shapes):
            obj = pin.GeometryObject(f'scene/{i}', 0, 0, shape.pose.to_se3(), coal_geometry(shape))
            self.geom_model.addGeometryObject(obj)
        self.geom_model.removeAllCollisionPairs()
        for a, b in robot.self_pairs:
            self.geom_model.addCollisionPair(pin.CollisionPair(a, b))
        for pair in self._scene_pairs():
            self.geom_model.addCollisionPair(pair)
        self._threads = threading.local()
        self._occupied: BoundedCache = BoundedCache('occupied voxels of a scene', 8)

    def create_data(self) -> CollisionData:
        """Fresh scratch for queries on this world (one per thread)."""
        return CollisionData(self)

    @property
    def scratch(self) -> CollisionData:
        """The calling thread's ``CollisionData`` (made on its first query)."""
        scratch = getattr(self._threads, 'scratch', None)
        if scratch is None:
            scratch = self._threads.scratch = self.create_data()
        return scratch

    @property
    def data(self) -> pin.Data:
        return self.scratch.data

    @property
    def geom_data(self) -> pin.GeometryData:
        return self.scratch.geom_data

    @property
    def dist_data(self) -> pin.GeometryData:
        scratch = self.scratch
        if scratch.dist_data is None:
            scratch.dist_data = self.dist_model.createData()
            no_warm_start(scratch.dist_data.distanceRequests)
        return scratch.dist_data

    @functools.cached_property
    def _primitives_only(self) -> bool:
        return all(shape.kind in ('box', 'sphere', 'cylinder') for shape in self.shapes)

    def _scene_pairs(self) -> list[pin.CollisionPair]:
        return [pin.CollisionPair(link, self.n_links + k)
                for link in range(self.n_links) for k in range(len(self.shapes))]

    @functools.cached_property
    def dist_model(self) -> pin.GeometryModel:
        """A copy holding only the (link, scene) pairs, so one C++ call gives the clearance
        (built on first use: validity checks never need it)."""
        dist_model = self.geom_model.copy()
        dist_model.removeAllCollisionPairs()
        for pair in self._scene_pairs():
            dist_model.addCollisionPair(pair)
        return dist_model

    def in_collision(self, q: np.ndarray) -> bool:
        """Self or scene collision at ``q`` (joint limits not checked)."""
        scratch = self.scratch
        return bool(pin.computeCollisions(self.model, scratch.data, scratch.broad, q, True))

    def is_valid(self, q: np.ndarray) -> bool:
        return self.robot.within_limits(q) and not self.in_collision(q)

    def colliding_pairs(self, q: np.ndarray, shape_names: list[str] | None = None
                        ) -> list[tuple[str, str]]:
        """Every colliding pair at ``q``: robot geometry names, scene shapes as
        ``shape_names[k]`` (default ``scene/k``)."""
        scratch = self.scratch
        pin.computeCollisions(self.model, scratch.data, self.geom_model, scratch.broad_data, q,
                              False)
        names = [g.name for g in self.geom_model.geometryObjects]
        if shape_names is not None:
            names[self.n_links:] = list(shape_names)
        return [(names[p.first], names[p.second])
                for p, r in zip(self.geom_model.collisionPairs,
                                scratch.broad_data.collisionResults)
                if r.isCollision()]

    def _broad_pool(self, threads: int):
        scratch = self.scratch
        if scratch.pool is None or scratch.pool.size() < threads:
            scratch.pool = pin.BroadPhaseManagerPool_DynamicAABBTreeCollisionManager(
                self.model, self.geom_model, max(threads, 1))
            for data in scratch.pool.getGeometryDatas():
                no_warm_start(data.collisionRequests)
        return scratch.pool

    def collisions_batch(self, Q: np.ndarray, threads: int = 1) -> np.ndarray:
        """Collision flags for configurations ``Q`` (N, nq), computed in parallel in C++."""
        return np.asarray(pin.computeCollisionsInParallel(
            max(threads, 1), self._broad_pool(threads), np.asfortranarray(Q.T), True, False),
            dtype=bool)

    def first_collision(self, Q: np.ndarray) -> int:
        """Index of the first configuration of ``Q`` (N, nq) in collision, in order; -1 if
        none. One C++ call that stops at the first collision: a motion's states are checked
        with no Python between them."""
        flags = np.asarray(pin.computeCollisionsInParallel(
            1, self._broad_pool(1), np.asfortranarray(Q.T), True, True), dtype=bool)
        return int(np.argmax(flags)) if flags.any() else -1

    def near_scene_batch(self, Q: np.ndarray, margin_m: float, threads: int = 1) -> np.ndarray:
        """Which configurations ``Q`` (N, nq) bring a link within ``margin_m`` of the scene."""
        scratch = self.scratch
        if not self.shapes:
            return np.zeros(len(Q), dtype=bool)
        if scratch.margin_pool is None or scratch.margin_pool[0] != margin_m:
            pool = pin.GeometryPool(self.model, self.dist_model, max(threads, 1))
            for data in pool.getGeometryDatas():
                no_warm_start(data.collisionRequests)
                for req in data.collisionRequests:
                    req.security_margin = margin_m
            scratch.margin_pool = (margin_m, pool)
        return np.asarray(pin.computeCollisionsInParallel(
            max(threads, 1), scratch.margin_pool[1], np.asfortranarray(Q.T), True, False),
            dtype=bool)

    def scene_distance(self, q: np.ndarray, upto_m: float | None = None) -> float:
        """Minimum distance between robot links and scene shapes [m]; ``inf`` if no scene.

        With ``upto_m``, the result is capped at ``upto_m``. Where the scene has meshes or
        clouds, only (link, shape) pairs closer than ``upto_m`` (found by one collision pass
        with that security margin) get a distance query: the same minimum wherever it is below
        ``upto_m`` (up to coal's tolerance at the margin), and ~1.8x faster (coal's octree
        distance costs ~0.7 ms per link). With primitives only, one C++ pass over every pair
        is faster still (135 vs 174 us on table_pick, same values).
        """
        scratch = self.scratch
        if not self.shapes:
            return float('inf')
        if upto_m is None or self._primitives_only:
            # pinocchio returns the index of the closest pair: no Python loop over the results.
            i = pin.computeDistances(self.model, scratch.data, self.dist_model,
                                     self.dist_data, q)
            d = float(self.dist_data.distanceResults[i].min_distance)
            return d if upto_m is None else min(d, float(upto_m))
        if scratch.near_data is None or scratch.near_data[0] != upto_m:
            near_data = self.dist_model.createData()
            no_warm_start(near_data.collisionRequests)
            for req in near_data.collisionRequests:
                req.security_margin = upto_m
            scratch.near_data = (upto_m, near_data)
        near_data = scratch.near_data[1]
        pin.updateGeometryPlacements(self.model, scratch.data, self.dist_model, near_data, q)
        pin.computeCollisions(self.dist_model, near_data, False)
        near = [k for k, r in enumerate(near_data.collisionResults) if r.isCollision()]
        if not near:
            return float(upto_m)
        pin.updateGeometryPlacements(self.model, scratch.data, self.dist_model,
                                     self.dist_data, q)
        return float(min(pin.computeDistance(self.dist_model, self.dist_data, k).min_distance
                         for k in near))

    def scene_clearances(self, Q: np.ndarray, upto_m: float) -> np.ndarray:
        """``scene_distance(q, upto_m)`` for each q of ``Q`` (N, nq) [m].

        Scenes of primitives: only the (link, shape) pairs whose axis-aligned bounds come
        within ``upto_m`` get a distance query (a pair farther than that is capped anyway), the
        bounds of all links and configurations computed at once: the same values, 1.6-2.2x
        faster than one ``scene_distance`` per configuration on the Panda scenes (measured;
        0.5-0.8x on the UR5 and xArm7 tables, whose few shapes leave little to skip). Other
        scenes: one call each.
        """
        scratch = self.scratch
        out = np.full(len(Q), float(upto_m))
        if not self.shapes or not len(Q):
            return out if self.shapes else np.full(len(Q), np.inf)
        if not self._primitives_only:
            return np.array([self.scene_distance(q, upto_m) for q in Q])
        H = self.link_transforms(Q)
        lo, hi = (b[:self.n_links] for b in self.robot.link_bounds_m)
        center = H[:, :, :3, 3] + np.einsum('nlij,lj->nli', H[:, :, :3, :3], (lo + hi) / 2)
        half = np.einsum('nlij,lj->nli', np.abs(H[:, :, :3, :3]), (hi - lo) / 2)
        s_lo, s_hi = (np.array([sh.bounds_m()[b] for sh in self.shapes]) for b in (0, 1))
        gap = np.maximum(s_lo[None, None] - (center + half)[:, :, None],
                         (center - half)[:, :, None] - s_hi[None, None])  # (N, L, S, 3)
        near = np.linalg.norm(np.maximum(gap, 0.0), axis=-1) < upto_m + 1e-9  # (N, L, S)
        n_shapes = len(self.shapes)
        for i in np.flatnonzero(near.any(axis=(1, 2))):
            pin.updateGeometryPlacements(self.model, scratch.data, self.dist_model,
                                         self.dist_data, Q[i])
            for li, k in zip(*np.nonzero(near[i])):
                d = pin.computeDistance(self.dist_model, self.dist_data,
                                        int(li) * n_shapes + int(k)).min_distance
                out[i] = min(out[i], d)
        return out

    def link_transforms(self, Q: np.ndarray) -> np.ndarray:
        """``T_base_geom`` of each robot collision geometry for each q of ``Q``, as
        (N, n_links, 4, 4) homogeneous matrices: the joints' frames of every q composed with
        the geometries' fixed placements in one compiled pass (``kinematics.batch.JointFrames``;
        pinocchio's forward kinematics q by q, and numpy, for a joint it does not model)."""
        geoms = self.geom_model.geometryObjects[:self.n_links]
        kinematics = self._kinematics
        placements = np.array([g.placement.homogeneous for g in geoms])
        if kinematics.supports:
            return kinematics.placed(Q, [g.parentJoint for g in geoms], placements)
        column = [kinematics.column[g.parentJoint] for g in geoms]
        return np.einsum('nlij,ljk->nlik', self._joint_frames_pin(Q)[:, column], placements)

    @functools.cached_property
    def _kinematics(self):
        """The links' joints as ``JointFrames`` (imported here: the kernels only when asked)."""
        from advocc_ros.kinematics.batch import JointFrames

        return JointFrames(self.model, [g.parentJoint for g in
                                        self.geom_model.geometryObjects[:self.n_links]])

    def _joint_frames_pin(self, Q: np.ndarray) -> np.ndarray:
        """T_base_joint (N, joints + 1, 4, 4) of ``JointFrames``' joints in its ``column`` order,
        by pinocchio, one forward kinematics per q."""
        joints = sorted(self._kinematics.column, key=self._kinematics.column.get)
        data = self.model.createData()  # oMi[0], the base, stays the identity
        T_joint = np.empty((len(Q), len(joints), 4, 4))
        for i, q in enumerate(Q):
            pin.forwardKinematics(self.model, data, q)
            for a, j in enumerate(joints):
                T_joint[i, a] = data.oMi[j].homogeneous
        return T_joint

    def occupied(self, grid: VoxelGrid) -> np.ndarray:
        """Voxels of ``grid`` whose centre lies inside a scene shape, computed once per grid:
        every attack request on this scene reuses it."""
        return self._occupied.get_or_make(grid, lambda: occupied_mask(grid, self.shapes))

    def link_placements(self, q: np.ndarray) -> list[pin.SE3]:
        """``T_base_geom`` of each robot collision geometry at ``q``."""
        scratch = self.scratch
        pin.updateGeometryPlacements(self.model, scratch.data, self.geom_model,
                                     scratch.geom_data, q)
        return [scratch.geom_data.oMg[i] for i in range(self.n_links)]

    def shape_collides(self, shape: Shape, q: np.ndarray | None = None,
                       margin_m: float = 0.0) -> bool:
        """Whether ``shape`` is within ``margin_m`` of the scene, or of the robot at ``q``."""
        scratch = self.scratch
        geom = coal_geometry(shape)
        tf = _coal_tf(shape.pose.to_se3())
        req = coal.DistanceRequest()
        res = coal.DistanceResult()
        if q is not None:
            pin.updateGeometryPlacements(self.model, scratch.data, self.geom_model,
                                         scratch.geom_data, q)
            others = range(self.geom_model.ngeoms)
        else:
            others = range(self.n_links, self.geom_model.ngeoms)
        for i in others:
            other = self.geom_model.geometryObjects[i].geometry
            oMg = scratch.geom_data.oMg[i] if i < self.n_links else \
                self.geom_model.geometryObjects[i].placement
            res.clear()
            if coal.distance(geom, tf, other, _coal_tf(oMg), req, res) < margin_m:
                return True
        return False


SHARED_WORLDS: BoundedCache = BoundedCache('collision worlds', 8)
"""(robot hash, shape fingerprints) -> CollisionWorld, shared by every thread
(:func:`shared_world`); kept across tasks."""


def shared_world(robot: RobotModel, shapes: list[Shape] = ()) -> CollisionWorld:
    """The ``CollisionWorld`` of (robot, shapes), reused by later calls with the same robot and
    geometry. An attack service answers many requests on one scene; building its world (~1 ms
    for 10 shapes, the same every time) need not be paid per request. Threads share it: each
    queries on its own ``CollisionData``."""
    key = (robot.hash, json.dumps([s.fingerprint() for s in shapes]))
    return SHARED_WORLDS.get_or_make(key, lambda: CollisionWorld(robot, shapes))


def no_warm_start(requests) -> None:
    """Start every GJK from the default guess: pinocchio enables warm starts from the previous
    query, which makes distances (to ~1e-5 m) depend on the order configurations were checked
    in, and heatmaps built in shards or by several workers differ from a serial build."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        for req in requests:
            req.enable_cached_gjk_guess = False
            req.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess


def _coal_tf(T: pin.SE3) -> coal.Transform3s:
    return coal.Transform3s(T.rotation, T.translation)
