"""heatmap_server for other robots: a UR5 attack round trip, and a Panda heatmap built with open
fingers served with open fingers (the locked joints come from the heatmap file, docs/design.md)."""

import dataclasses
import json

import pytest

from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
from advocc_ros.model.scene import load_scene
from conftest import REPO
from test_attack_nodes import _call, _start, _stop, _wait_service

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

UR5 = ('robot_urdf:=example-robot-data://ur_description/urdf/ur5_robot.urdf',
       'robot_srdf:=example-robot-data://ur_description/srdf/ur5.srdf', "robot_group:=''",
       'robot_ee_link:=tool0', 'base_frame:=base_link')


def _server(ros, ros_env, path, *params):
    from advocc_msgs.srv import Attack, GetInfo
    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={path}', *params)
    children.append(server)
    attack = node.create_client(Attack, '/heatmap_server/attack')
    info = node.create_client(GetInfo, '/heatmap_server/get_info')
    _wait_service(executor, info, server)
    return server, executor, attack, json.loads(
        _call(executor, info, GetInfo.Request()).info_json)


def test_ur5_attack_round_trip(ros, ros_env, tmp_path):
    from advocc_ros.ros.conversions import attack_request
    scene = load_scene(REPO / 'config' / 'scenes' / 'ur5_table.yaml')
    path = tmp_path / 'ur5.npz'
    save_heatmap(build_heatmap(scene, HeatmapConfig(samples=200), seed=1), path)
    server, executor, attack, info = _server(ros, ros_env, path, *UR5)
    assert info['robot']['ee_link'] == 'tool0' and len(info['robot']['joints']) == 6
    _wait_service(executor, attack, server)
    response = _call(executor, attack, attack_request(scene, 2, 'ours'), timeout_s=60)
    assert response.error_code.val == 1, response.error_code.message
    assert len(response.obstacles) == 2
    assert _stop(server) == 0


def test_panda_heatmap_with_open_fingers_serves_with_open_fingers(ros, ros_env, tmp_path,
                                                                  table_scene):
    opened = dict(table_scene.start, panda_finger_joint1=0.04, panda_finger_joint2=0.04)
    scene = dataclasses.replace(table_scene, start=opened)
    assert dict(scene.robot.locked)['panda_finger_joint1'] == 0.04
    path = tmp_path / 'open.npz'
    save_heatmap(build_heatmap(scene, HeatmapConfig(samples=100), seed=1), path)
    server, _, _, info = _server(ros, ros_env, path)  # the default (Panda) parameters
    assert info['robot']['locked'] == {'panda_finger_joint1': 0.04, 'panda_finger_joint2': 0.04}
    assert _stop(server) == 0


def test_robot_locked_parameter_overrides_the_file(ros_env, tmp_path, table_scene):
    """Values other than the heatmap's make another robot: refused at start-up (exit 1)."""
    path = tmp_path / 'closed.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=100), seed=1), path)
    proc = _start('heatmap_server', ros_env, f'heatmap_file:={path}',
                  "robot_locked:=['panda_finger_joint1=0.02','panda_finger_joint2=0.02']")
    try:
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 1 and 'not this robot' in out


@pytest.mark.parametrize('entries, expected', [
    ([''], None), (['a=0.5', 'b = 1'], (('a', 0.5), ('b', 1.0)))])
def testparse_locked(entries, expected):
    from advocc_ros.nodes.heatmap_server import parse_locked
    assert parse_locked(entries) == expected


@pytest.mark.parametrize('bad', [['a'], ['=1'], ['a=x'], ['a=nan']])
def testparse_locked_refuses(bad):
    from advocc_ros.model.robot import RobotError
    from advocc_ros.nodes.heatmap_server import parse_locked
    with pytest.raises(RobotError):
        parse_locked(bad)
