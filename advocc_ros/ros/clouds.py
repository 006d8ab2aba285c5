"""sensor_msgs/PointCloud2 in and out, and RViz markers of scene objects.

Clouds in: xyz of any float32/float64 layout (organized or not, either byte order); non-finite
points (an organized camera cloud marks missing pixels with NaN) are dropped, the rest is
cropped to a box and becomes a cloud shape (the octree of ``advocc_ros.model.cloud``), the way
MoveIt's occupancy-map updater turns a depth sensor's cloud into its octomap.
Clouds out: the heatmap's hottest voxels with x, y, z, intensity (= H) float32 fields.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose as PoseMsg
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from advocc_ros.limits import MAX_CLOUD_POINTS, MAX_CLOUD_RESOLUTION_M, MIN_CLOUD_RESOLUTION_M
from advocc_ros.model.cloud import make_cloud_shape
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import SceneObject
from advocc_ros.model.shapes import Shape, cloud_cells
from advocc_ros.ros.params import Param

CLOUD_TOPIC = '/advocc/cloud'
CLOUD_PARAMETERS = (
    Param('cloud_resolution', 0.02, f'{CLOUD_TOPIC}: octree leaf edge [m]',
          low=MIN_CLOUD_RESOLUTION_M, high=MAX_CLOUD_RESOLUTION_M),
    Param('cloud_crop_min', [-1.5, -1.5, -0.5], f'{CLOUD_TOPIC}: crop box corner, robot base '
          'frame [m]; points outside the box are ignored, like MoveIt\'s updater\'s max range'),
    Param('cloud_crop_max', [1.5, 1.5, 2.0], f'{CLOUD_TOPIC}: opposite crop box corner [m]'))
"""Parameters of a node that reads ``/advocc/cloud``."""
_NUMPY = {PointField.FLOAT32: 'f4', PointField.FLOAT64: 'f8'}


def points_from_cloud_msg(msg: PointCloud2, where: str = 'cloud') -> np.ndarray:
    """(N, 3) finite xyz points of a PointCloud2 (NaN/inf points dropped)."""
    fields = {f.name: f for f in msg.fields}
    if not {'x', 'y', 'z'} <= set(fields):
        raise SceneError(f'{where}: fields {sorted(fields)} lack x, y, z')
    n = int(msg.width) * int(msg.height)
    if n > MAX_CLOUD_POINTS:
        raise SceneError(f'{where}: {n:,} points, limit {MAX_CLOUD_POINTS:,} (MAX_CLOUD_POINTS)')
    if n == 0:
        return np.zeros((0, 3))
    order = '>' if msg.is_bigendian else '<'
    step = int(msg.point_step)
    names, formats, offsets = [], [], []
    for axis in 'xyz':
        f = fields[axis]
        if f.datatype not in _NUMPY or f.count != 1:
            raise SceneError(f'{where}: field {axis} must be one float32/float64')
        if f.offset + np.dtype(_NUMPY[f.datatype]).itemsize > step:
            raise SceneError(f'{where}: field {axis} at byte {f.offset} does not fit in a point '
                             f'of {step} bytes (point_step)')
        names.append(axis)
        formats.append(order + _NUMPY[f.datatype])
        offsets.append(f.offset)
    if int(msg.row_step) < step * int(msg.width) or len(msg.data) < int(msg.row_step) * \
            (int(msg.height) - 1) + step * int(msg.width):
        raise SceneError(f'{where}: {len(msg.data)} data bytes do not hold {msg.height} x '
                         f'{msg.width} points of {step} bytes')
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': step})
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    rows = [np.frombuffer(raw[r * msg.row_step:r * msg.row_step + step * msg.width].tobytes(),
                          dtype=dtype) for r in range(msg.height)]
    rec = np.concatenate(rows)
    pts = np.stack([rec['x'], rec['y'], rec['z']], axis=-1).astype(float)
    return pts[np.all(np.isfinite(pts), axis=1)]


def cloud_shape_from_msg(msg: PointCloud2, resolution_m: float, crop_min_m, crop_max_m,
                         where: str = 'cloud') -> Shape | None:
    """Cloud shape of a PointCloud2's points inside the crop box (None: no point left)."""
    pts = points_from_cloud_msg(msg, where)
    lo, hi = np.asarray(crop_min_m, float), np.asarray(crop_max_m, float)
    pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    if len(pts) == 0:
        return None
    return make_cloud_shape(pts, resolution_m, where=where)


def cloud_msg(points_m: np.ndarray, frame: str, intensity: np.ndarray | None = None
              ) -> PointCloud2:
    """Unorganized float32 PointCloud2 with x, y, z (and intensity if given)."""
    names = ['x', 'y', 'z'] + (['intensity'] if intensity is not None else [])
    cols = [np.asarray(points_m, float).reshape(-1, 3)]
    if intensity is not None:
        cols.append(np.asarray(intensity, float).reshape(-1, 1))
    table = np.ascontiguousarray(np.hstack(cols).astype('<f4'))
    msg = PointCloud2()
    msg.header.frame_id = frame
    msg.height, msg.width = 1, len(table)
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, n in enumerate(names)]
    msg.is_bigendian = False
    msg.point_step = 4 * len(names)
    msg.row_step = msg.point_step * msg.width
    msg.is_dense = True
    msg.data = table.tobytes()
    return msg


def _pose_msg(pose: Pose) -> PoseMsg:
    msg = PoseMsg()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in pose.position_m)
    (msg.orientation.x, msg.orientation.y, msg.orientation.z,
     msg.orientation.w) = (float(v) for v in pose.quat_xyzw)
    return msg


def scene_cloud(objects) -> tuple[np.ndarray, float] | None:
    """The cloud objects among ``objects`` as one (points in the base frame (N, 3), finest
    resolution) pair for ``/advocc/cloud`` or a request's ``cloud``; None without clouds."""
    shapes = [s for o in objects for s in o.shapes if s.kind == 'cloud']
    if not shapes:
        return None
    points = []
    for shape in shapes:
        T = shape.pose.to_se3()
        points.append(np.asarray(shape.vertices) @ T.rotation.T + T.translation)
    return np.concatenate(points), min(s.dims[0] for s in shapes)


def without_clouds(objects) -> tuple[SceneObject, ...]:
    """``objects`` minus their cloud shapes (what CollisionObject messages can carry)."""
    out = []
    for obj in objects:
        shapes = tuple(s for s in obj.shapes if s.kind != 'cloud')
        if shapes:
            out.append(SceneObject(obj.id, shapes))
    return tuple(out)


def _color(r: float, g: float, b: float, a: float) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=a)


def scene_markers(objects, frame: str, ns: str, start_id: int = 0) -> list[Marker]:
    """One marker per shape of the scene's objects (grey; clouds as cubes of their leaves)."""
    markers = []
    for obj in objects:
        for shape in obj.shapes:
            m = Marker(ns=ns, id=start_id + len(markers), action=Marker.ADD)
            m.header.frame_id = frame
            m.pose = _pose_msg(shape.pose)
            m.color = _color(0.6, 0.6, 0.65, 0.6)
            m.text = obj.id
            if shape.kind == 'box':
                m.type = Marker.CUBE
                m.scale.x, m.scale.y, m.scale.z = (float(v) for v in shape.dims)
            elif shape.kind == 'sphere':
                m.type = Marker.SPHERE
                m.scale.x = m.scale.y = m.scale.z = 2.0 * shape.dims[0]
            elif shape.kind == 'cylinder':
                m.type = Marker.CYLINDER
                m.scale.x = m.scale.y = 2.0 * shape.dims[1]
                m.scale.z = float(shape.dims[0])
            elif shape.kind == 'cloud':
                res = shape.dims[0]
                m.type = Marker.CUBE_LIST
                m.scale.x = m.scale.y = m.scale.z = res
                m.color = _color(0.3, 0.6, 0.9, 0.8)
                m.points = [Point(x=float(c[0]), y=float(c[1]), z=float(c[2]))
                            for c in (cloud_cells(shape.vertices, res) + 0.5) * res]
            else:
                m.type = Marker.TRIANGLE_LIST
                m.scale.x = m.scale.y = m.scale.z = 1.0
                v = np.asarray(shape.vertices)[np.asarray(shape.faces).ravel()]
                m.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in v]
            markers.append(m)
    return markers


def markers_with_scene(boxes: MarkerArray, objects: tuple[SceneObject, ...], frame: str,
                       ns: str) -> MarkerArray:
    """``boxes`` (starting with a DELETEALL) followed by the scene's object markers."""
    out = MarkerArray()
    out.markers = list(boxes.markers) + scene_markers(objects, frame, ns)
    return out


def cloud_shape_from_node_params(node, msg: PointCloud2) -> Shape | None:
    """The cloud shape of ``msg`` with ``node``'s cloud parameters (None: nothing in the box)."""
    return cloud_shape_from_msg(msg, node.get_parameter('cloud_resolution').value,
                                node.get_parameter('cloud_crop_min').value,
                                node.get_parameter('cloud_crop_max').value)
