"""Shapes of scene objects: poses, primitives, triangle meshes and sensed point clouds.

Everything is in the robot base frame, in metres; quaternions are ``[x, y, z, w]`` as in ROS
messages. ``advocc_ros.model.scene`` re-exports these names.
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib
from typing import TYPE_CHECKING

import numpy as np

from advocc_ros.limits import MAX_FILE_BYTES, MAX_MESH_TRIANGLES, MAX_MESH_VERTICES
from advocc_ros.model.pose import Pose, SceneError, finite_array

if TYPE_CHECKING:  # trimesh (0.3 s to import) loads only where a mesh is made or read
    import trimesh

SHAPES = ('box', 'sphere', 'cylinder', 'mesh', 'cloud')


@dataclasses.dataclass(frozen=True)
class Shape:
    """One solid: a primitive, a triangle mesh or a sensed point cloud, posed in the base frame.

    A cloud is occupied where an octree leaf of edge ``resolution`` holds a point (coal's
    ``OcTree``: the FCL/MoveIt octomap semantics); see ``advocc_ros.model.cloud``.
    """

    kind: str
    """box | sphere | cylinder | mesh | cloud"""
    dims: tuple[float, ...] = ()
    """box: (x, y, z) edge lengths; sphere: (radius,); cylinder: (height, radius) as in
    shape_msgs/SolidPrimitive; mesh: (); cloud: (resolution,) = octree leaf edge [m]."""
    pose: Pose = Pose()
    vertices: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)
    """mesh: (V, 3) vertices; cloud: (N, 3) points; in the shape frame [m]."""
    faces: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)
    """mesh only: (F, 3) vertex indices."""

    def trimesh(self) -> trimesh.Trimesh:
        """Solid of the shape in the base frame (a cloud: its occupied octree cells)."""
        import trimesh
        if self.kind == 'box':
            mesh = trimesh.creation.box(extents=self.dims)
        elif self.kind == 'sphere':
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=self.dims[0])
        elif self.kind == 'cylinder':
            mesh = trimesh.creation.cylinder(radius=self.dims[1], height=self.dims[0],
                                             sections=32)
        elif self.kind == 'cloud':
            mesh = _cells_mesh(cloud_cells(self.vertices, self.dims[0]), self.dims[0])
        else:
            mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        mesh.apply_transform(self.pose.to_se3().homogeneous)
        return mesh

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned (lo, hi) bounds in the base frame [m] (cheap, possibly loose)."""
        T = self.pose.to_se3()
        if self.kind == 'box':
            ext = np.abs(T.rotation) @ (np.asarray(self.dims) / 2)
        elif self.kind == 'sphere':
            ext = np.full(3, self.dims[0])
        elif self.kind == 'cylinder':
            ext = np.full(3, float(np.hypot(self.dims[0] / 2, self.dims[1])))
        else:
            pts = np.asarray(self.vertices) @ T.rotation.T + T.translation
            # A cloud's points lie in cells of edge ``resolution``: pad by a cell diagonal.
            pad = float(np.sqrt(3) * self.dims[0]) if self.kind == 'cloud' else 0.0
            return pts.min(axis=0) - pad, pts.max(axis=0) + pad
        return T.translation - ext, T.translation + ext

    def fingerprint(self) -> list:
        data = [self.kind, [round(d, 9) for d in self.dims], self.pose.to_data()]
        if self.kind == 'mesh':
            data.append(hashlib.sha256(np.ascontiguousarray(self.vertices).tobytes()
                                       + np.ascontiguousarray(self.faces).tobytes()).hexdigest())
        elif self.kind == 'cloud':
            data.append(hashlib.sha256(np.ascontiguousarray(self.vertices).tobytes()).hexdigest())
        return data


def mesh_shape_from_data(entry: dict, where: str, base_dir: pathlib.Path | None,
                         pose: Pose) -> Shape:
    """A ``type: mesh`` scene-file entry (``file`` or inline ``vertices`` and ``faces``)."""
    scale = finite_array(entry.get('scale', [1, 1, 1]), f'{where}.scale', 3, positive=True)
    if 'file' in entry:
        path = pathlib.Path(str(entry['file']))
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        if path.suffix.lower() not in ('.stl', '.obj', '.ply'):
            raise SceneError(f'{where}.file: {path} is not an STL, OBJ or PLY file')
        if not path.is_file():
            raise SceneError(f'{where}.file: {path} not found')
        if path.stat().st_size > MAX_FILE_BYTES:
            raise SceneError(f'{where}.file: {path} is {path.stat().st_size} bytes, limit '
                             f'{MAX_FILE_BYTES} (MAX_FILE_BYTES)')
        import trimesh
        try:
            mesh = trimesh.load_mesh(str(path), force='mesh')
        except Exception as exc:  # trimesh raises many types on bad files
            raise SceneError(f'{where}.file: {path} could not be read ({exc})') from exc
        vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    elif 'vertices' in entry and 'faces' in entry:
        vertices = finite_array(entry['vertices'], f'{where}.vertices')
        try:
            faces = np.asarray(entry['faces'], dtype=np.int64)
        except (TypeError, ValueError):
            raise SceneError(f'{where}.faces: expected integer triples') from None
    else:
        raise SceneError(f'{where}: a mesh needs file, or vertices and faces')
    return make_mesh_shape(vertices * scale, faces, pose, where)


def make_mesh_shape(vertices, faces, pose: Pose, where: str = 'mesh') -> Shape:
    """Validated mesh shape (bounded size, indices in range, non-degenerate)."""
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 4:
        raise SceneError(f'{where}.vertices: expected at least 4 points (V, 3)')
    if len(vertices) > MAX_MESH_VERTICES:
        raise SceneError(f'{where}.vertices: {len(vertices)} vertices, limit {MAX_MESH_VERTICES}')
    if not np.all(np.isfinite(vertices)):
        raise SceneError(f'{where}.vertices: non-finite values')
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) < 4:
        raise SceneError(f'{where}.faces: expected at least 4 triangles (F, 3)')
    if len(faces) > MAX_MESH_TRIANGLES:
        raise SceneError(f'{where}.faces: {len(faces)} triangles, limit {MAX_MESH_TRIANGLES}')
    if not np.issubdtype(faces.dtype, np.integer) or faces.min() < 0 \
            or faces.max() >= len(vertices):
        raise SceneError(f'{where}.faces: vertex indices out of range 0..{len(vertices) - 1}')
    if np.ptp(vertices, axis=0).min() <= 0:
        raise SceneError(f'{where}.vertices: the mesh is flat (zero volume)')
    return Shape('mesh', (), pose, vertices, faces.astype(np.int64))


def cloud_cells(points_local: np.ndarray, resolution_m: float) -> np.ndarray:
    """(M, 3) integer indices of the octree leaves holding a point: cell ``k`` spans
    ``k * resolution_m`` to ``(k + 1) * resolution_m`` in the cloud's frame, as octomap keys do."""
    return np.unique(np.floor(np.asarray(points_local) / resolution_m).astype(np.int64), axis=0)


def _cells_mesh(cells: np.ndarray, resolution_m: float) -> trimesh.Trimesh:
    """One cube per cell, in the cloud's frame."""
    import trimesh
    cube = trimesh.creation.box(extents=(resolution_m,) * 3)
    centers = (cells + 0.5) * resolution_m
    vertices = (cube.vertices[None] + centers[:, None]).reshape(-1, 3)
    faces = (cube.faces[None] + 8 * np.arange(len(cells))[:, None, None]).reshape(-1, 3)
    return trimesh.Trimesh(vertices, faces, process=False)
