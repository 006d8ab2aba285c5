"""Inputs ``make fuzz`` found that crashed a parser or node or got an unclear error: each is
refused now with the documented error type and a message that names what is wrong."""

import io

import numpy as np
import pytest


def _cloud_msg(**changes):
    from sensor_msgs.msg import PointCloud2, PointField
    pts = np.array([[0.6, 0.0, 0.8], [0.6, 0.05, 0.8]], dtype=np.float32)
    msg = PointCloud2(height=1, width=2, point_step=12, row_step=24, data=pts.tobytes())
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, n in enumerate('xyz')]
    for key, value in changes.items():
        setattr(msg, key, value)
    return msg


def test_good_cloud_message_reads():
    from advocc_ros.ros.clouds import points_from_cloud_msg
    assert points_from_cloud_msg(_cloud_msg()).shape == (2, 3)


@pytest.mark.parametrize('changes', [
    {'point_step': 11, 'row_step': 22},  # numpy: 'requires 12 bytes' ValueError, was FAILURE
    {'point_step': 4, 'row_step': 8},
])
def test_cloud_message_whose_fields_overrun_the_point_is_refused(changes):
    from advocc_ros.model.scene import SceneError
    from advocc_ros.ros.clouds import points_from_cloud_msg
    with pytest.raises(SceneError, match='does not fit in a point of'):
        points_from_cloud_msg(_cloud_msg(**changes))


def test_cloud_message_with_a_huge_field_offset_is_refused():
    """An offset of 2^32 - 1 overflowed numpy's C int ('integer won't fit'), was FAILURE."""
    from advocc_ros.model.scene import SceneError
    from advocc_ros.ros.clouds import points_from_cloud_msg
    msg = _cloud_msg()
    msg.fields[1].offset = 2 ** 32 - 1
    with pytest.raises(SceneError, match='field y at byte 4294967295'):
        points_from_cloud_msg(msg)


def test_heatmap_with_an_infinite_format_version_is_refused(tmp_path):
    """``int(inf)`` raised a bare OverflowError."""
    from advocc_ros.heatmap import HeatmapError, load_heatmap
    buf = io.BytesIO()
    np.savez(buf, format_version=np.array(np.inf), origin_m=np.zeros(3), voxel_m=np.array(0.1),
             shape=np.array([1, 1, 1]), values=np.zeros((1, 1, 1)), free=np.ones((1, 1, 1), bool),
             meta_json=np.frombuffer(b'{}', np.uint8))
    path = tmp_path / 'inf_version.npz'
    path.write_bytes(buf.getvalue())
    with pytest.raises(HeatmapError, match='format_version is not an integer'):
        load_heatmap(path)
