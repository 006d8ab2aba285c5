"""Clouds and RViz over ROS with real processes: the latched heatmap cloud, a sensed scene
through the heatmap server, the attacker and the planner shim."""

import time

import numpy as np
import pytest

from test_attack_nodes import _call, _start, _stop, _wait_service

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


@pytest.fixture(scope='module')
def sensed_table(table_scene):
    from advocc_ros.scenes.sensing import sensed_scene
    return sensed_scene(table_scene)


def _spin_until(executor, done, procs, timeout_s=60, what='message'):
    deadline = time.monotonic() + timeout_s
    while not done():
        for proc in procs:
            assert proc.poll() is None, f'{proc.args[2]} exited:\n{proc.stdout.read()}'
        if time.monotonic() > deadline:
            for proc in procs:
                proc.kill()
            logs = '\n'.join(f'--- {p.args[2]}:\n{p.communicate(timeout=10)[0]}' for p in procs)
            pytest.fail(f'no {what} within {timeout_s} s\n{logs}')
        executor.spin_once(timeout_sec=0.1)


def test_a_late_subscriber_gets_the_heatmap_cloud(ros, ros_env, heatmap_file):  # noqa: F811
    from advocc_msgs.srv import GetInfo
    from sensor_msgs.msg import PointCloud2

    from advocc_ros.heatmap import hottest_voxels, load_heatmap
    from advocc_ros.ros.clouds import points_from_cloud_msg
    from advocc_ros.ros.qos import LATCHED_QOS

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    children.append(server)
    _wait_service(executor, node.create_client(GetInfo, '/heatmap_server/get_info'), server)
    time.sleep(1.0)  # published well before we subscribe: only latching delivers it
    got = []
    node.create_subscription(PointCloud2, '/heatmap_server/heatmap', got.append, LATCHED_QOS)
    _spin_until(executor, lambda: got, [server], 30, 'heatmap cloud')
    msg = got[0]
    assert msg.header.frame_id == 'panda_link0'
    assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'intensity']
    assert msg.width * msg.height >= 1000
    points, H = hottest_voxels(load_heatmap(heatmap_file))
    np.testing.assert_allclose(points_from_cloud_msg(msg), points, atol=1e-6)
    intensity = np.frombuffer(bytes(msg.data), '<f4').reshape(-1, 4)[:, 3]
    np.testing.assert_allclose(intensity, H, rtol=1e-6)
    assert _stop(server) == 0


def test_the_server_attacks_a_sensed_scene(ros, ros_env, heatmap_file, sensed_table):  # noqa: F811
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack

    from advocc_ros.ros.conversions import attack_request

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    children.append(server)
    client = node.create_client(Attack, '/heatmap_server/attack')
    _wait_service(executor, client, server)
    req = attack_request(sensed_table, 3, 'task')  # the cloud goes in req.cloud
    assert not req.scene and req.cloud.width == len(sensed_table.shapes[0].vertices)
    assert req.cloud_resolution == 0.02
    res = _call(executor, client, req, timeout_s=60)
    assert res.error_code.val == ErrorCodes.SUCCESS, res.message
    assert len(res.obstacles) == 3
    req.cloud.header.frame_id = 'camera'
    res = _call(executor, client, req, timeout_s=60)
    assert res.error_code.val == ErrorCodes.INVALID_REQUEST and 'camera' in res.message
    assert _stop(server) == 0


def test_attacker_and_shim_take_the_cloud_topic(ros, ros_env, heatmap_file,  # noqa: F811
                                                sensed_table, tmp_path):
    from advocc_msgs.msg import CollisionObject, GoalRegion, Scene
    from advocc_msgs.srv import GetInfo
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker, MarkerArray

    from advocc_ros.model.scene import save_yaml_atomic
    from advocc_ros.ros.clouds import CLOUD_TOPIC, cloud_msg
    from advocc_ros.ros.conversions import goal_region_to_msg, joint_state_from_dict
    from advocc_ros.ros.qos import (COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, LATCHED_QOS,
                                    SCENE_TOPIC)

    node, executor, children = ros
    empty = tmp_path / 'empty.yaml'
    save_yaml_atomic(empty, sensed_table.without_objects().to_data())
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    attacker = _start('attacker', ros_env, 'budget:=3', 'method:=task', 'timeout_s:=60.0')
    shim = _start('planner_shim', ros_env, f'scene_file:={empty}')
    children += [server, attacker, shim]
    ops, markers = [], []
    node.create_subscription(CollisionObject, COLLISION_OBJECT_TOPIC, ops.append, LATCHED_QOS)
    node.create_subscription(MarkerArray, '/attacker/markers', markers.append, LATCHED_QOS)
    shape = sensed_table.shapes[0]
    node.create_publisher(PointCloud2, CLOUD_TOPIC, LATCHED_QOS).publish(
        cloud_msg(shape.vertices, 'panda_link0'))
    msg = Scene(name=sensed_table.name, start_state=joint_state_from_dict(sensed_table.start))
    msg.header.frame_id = 'panda_link0'
    node.create_publisher(Scene, SCENE_TOPIC, LATCHED_QOS).publish(msg)
    node.create_publisher(GoalRegion, GOAL_REGION_TOPIC, LATCHED_QOS).publish(
        goal_region_to_msg(sensed_table.goal, 'panda_link0'))
    procs = [server, attacker, shim]
    _spin_until(executor, lambda: len(ops) >= 3, procs, 90, 'three boxes')
    assert [m.operation for m in ops[:3]] == [CollisionObject.ADD] * 3

    def cloud_marker():
        return [m for a in markers for m in a.markers if m.type == Marker.CUBE_LIST]
    _spin_until(executor, cloud_marker, procs, 20, 'cloud marker')
    assert len(cloud_marker()[-1].points) > 1000
    info_client = node.create_client(GetInfo, '/planner_shim/get_info')
    _wait_service(executor, info_client, shim)
    _spin_until(executor, lambda: 'sensed_cloud' in _call(
        executor, info_client, GetInfo.Request()).info_json, procs, 20, 'cloud in the shim')
    for proc in procs:
        assert _stop(proc) == 0


def test_the_shim_confines_cloud_files(ros_env, tmp_path, table_scene):
    """A scene inside allowed_dirs whose cloud file lies outside is refused at start-up."""
    import subprocess
    import sys

    from advocc_ros.model.scene import save_yaml_atomic

    allowed, outside = tmp_path / 'allowed', tmp_path / 'outside'
    allowed.mkdir()
    outside.mkdir()
    (outside / 'c.ply').write_text('ply\n')
    data = table_scene.without_objects().to_data()
    data['objects'] = [{'id': 'sensed', 'type': 'cloud', 'file': '../outside/c.ply'}]
    save_yaml_atomic(allowed / 's.yaml', data)
    proc = subprocess.run(
        [sys.executable, '-m', 'advocc_ros.nodes.planner_shim', '--ros-args',
         '-p', f'scene_file:={allowed / "s.yaml"}', '-p', f'allowed_dirs:=[{allowed}]'],
        env=ros_env, capture_output=True, text=True, timeout=120)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    assert 'outside the allowed' in out and 'c.ply' in out and 'Traceback' not in out, out


def _cloud(points, dtype='<f4', height=1, pad=0, fields='xyz'):
    from sensor_msgs.msg import PointCloud2, PointField
    pts = np.asarray(points, dtype=dtype)
    size = pts.dtype.itemsize
    datatype = PointField.FLOAT32 if size == 4 else PointField.FLOAT64
    msg = PointCloud2(height=height, width=len(pts) // height, is_bigendian=dtype[0] == '>')
    msg.fields = [PointField(name=n, offset=i * size, datatype=datatype, count=1)
                  for i, n in enumerate(fields)]
    msg.point_step = 3 * size
    msg.row_step = msg.point_step * msg.width + pad
    rows = pts.reshape(height, -1, 3)
    msg.data = b''.join(r.tobytes() + b'\0' * pad for r in rows)
    return msg


def test_clouds_have_no_collision_object_form(sensed_table, table_scene):
    from advocc_ros.model.pose import SceneError
    from advocc_ros.ros.conversions import collision_object_to_msg, scene_to_msg

    with pytest.raises(SceneError, match='PointCloud2'):
        collision_object_to_msg(sensed_table.objects[0], 'panda_link0')
    mixed = table_scene.with_objects(sensed_table.objects)
    assert [o.id for o in scene_to_msg(mixed).objects] == [o.id for o in table_scene.objects]


def test_point_cloud2_parsing_layouts_and_errors():
    from advocc_ros.model.pose import SceneError
    from advocc_ros.ros.clouds import cloud_shape_from_msg, points_from_cloud_msg

    pts = np.arange(36, dtype=float).reshape(12, 3) / 10
    for dtype in ('<f4', '>f4', '<f8'):
        np.testing.assert_allclose(points_from_cloud_msg(_cloud(pts, dtype)), pts, rtol=1e-6)
    organized = _cloud(pts, height=3, pad=8)  # 3 rows of 4 points, 8 padding bytes per row
    np.testing.assert_allclose(points_from_cloud_msg(organized), pts, rtol=1e-6)
    with_nan = pts.copy()
    with_nan[2, 1] = np.nan
    assert len(points_from_cloud_msg(_cloud(with_nan))) == 11  # missing pixels dropped
    with pytest.raises(SceneError, match='lack x, y, z'):
        points_from_cloud_msg(_cloud(pts, fields='xyw'))
    short = _cloud(pts)
    short.data = bytes(short.data)[:-4]
    with pytest.raises(SceneError, match='data bytes'):
        points_from_cloud_msg(short)
    shape = cloud_shape_from_msg(_cloud(pts), 0.05, [0, 0, 0], [1.5, 1.5, 1.5])
    assert len(shape.vertices) == 5 and shape.dims == (0.05,)  # cropped to the box
    assert cloud_shape_from_msg(_cloud(pts), 0.05, [10] * 3, [11] * 3) is None
    with pytest.raises(SceneError, match='resolution'):
        cloud_shape_from_msg(_cloud(pts), 5.0, [-9] * 3, [9] * 3)


def test_a_cloud_before_the_scene_waits_for_the_scenes_base_frame(ros, ros_env):  # noqa: F811
    """UR5 (base frame ``base_link``): the latched cloud reaches the attacker before the scene;
    it is kept and checked against the scene's frame, not dropped against a default one."""
    import threading

    from advocc_msgs.msg import Scene
    from sensor_msgs.msg import PointCloud2

    from advocc_ros.ros.clouds import CLOUD_TOPIC, cloud_msg
    from advocc_ros.ros.qos import LATCHED_QOS, SCENE_TOPIC

    node, executor, children = ros
    attacker = _start('attacker', ros_env)
    children.append(attacker)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(attacker.stdout), daemon=True)
    reader.start()
    points = np.array([[0.5, 0.0, 0.3], [0.5, 0.1, 0.3], [0.6, 0.0, 0.4]])
    node.create_publisher(PointCloud2, CLOUD_TOPIC, LATCHED_QOS).publish(
        cloud_msg(points, 'base_link'))
    _spin_until(executor, lambda: any('cloud received before the scene' in line
                                      for line in lines), [attacker], 60, 'early cloud')
    msg = Scene(name='ur5_table')
    msg.header.frame_id = 'base_link'
    node.create_publisher(Scene, SCENE_TOPIC, LATCHED_QOS).publish(msg)
    _spin_until(executor, lambda: any('cloud: 3 points' in line for line in lines),
                [attacker], 30, 'the cloud taken with the scene')
    assert _stop(attacker) == 0
    reader.join(10)
    assert not any('rejected' in line for line in lines), ''.join(lines)
