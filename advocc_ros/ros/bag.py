"""Attacks as ROS 2 bags: the scene, goal region, boxes and heatmap in rosbag2's MCAP format.

One ``.mcap`` file as rosbag2's MCAP storage (Jazzy's default) writes it: profile ``ros2``,
CDR messages serialized by rclpy, each type's schema the ``ros2msg`` text of its ``.msg`` file
with every nested definition appended, and the channels' offered QoS (latched topics stay
latched on ``ros2 bag play``). The topics are the ones the nodes publish, so RViz (through
``ros2 bag play``) and Foxglove show a bag like the live graph.
"""

from __future__ import annotations

import os
import pathlib
import re
import sys
import time

from mcap.writer import Writer
from rclpy.serialization import serialize_message

from advocc_ros.model.scene import Operation, Scene, SceneObject

SCENE_MARKERS_TOPIC = '/attacker/markers'
HEATMAP_TOPIC = '/heatmap_server/heatmap'
HEATMAP_PERCENTILE = 80.0
"""Voxels in the heatmap cloud: H at or above this percentile of the non-zero H (the server's
default ``heatmap_percentile``)."""
_BUILTIN = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
            'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}
_SEPARATOR = '=' * 80
# rosbag2's YAML of a latched (transient local, reliable, keep last 100) publisher, with the
# policies as integers: without a "rosbag2" metadata record (none is written) rosbag2 reads a
# channel's offered_qos_profiles in that form (its metadata version 8).
_LATCHED_QOS_YAML = ('- history: 1\n  depth: 100\n  reliability: 1\n  durability: 1\n'
                     '  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n'
                     '  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n'
                     '  liveliness: 1\n  liveliness_lease_duration:\n'
                     '    sec: 2147483647\n    nsec: 4294967295\n'
                     '  avoid_ros_namespace_conventions: false\n')


def _msg_file(package: str, name: str) -> pathlib.Path:
    """The installed ``.msg`` of ``package/msg/name`` (ament prefixes, then this Python's)."""
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in prefixes + [sys.prefix]:
        path = pathlib.Path(prefix) / 'share' / package / 'msg' / f'{name}.msg'
        if path.is_file():
            return path
    raise FileNotFoundError(f'message definition {package}/msg/{name}.msg not found under '
                            f'{prefixes + [sys.prefix]}')


def _field_types(text: str, package: str) -> list[str]:
    """``pkg/Type`` of each non-builtin field of a ``.msg`` text (constants skipped)."""
    out = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        kind = re.sub(r'\[[^\]]*\]$', '', line.split()[0])
        kind = re.sub(r'<=\d+$', '', kind)
        if kind in _BUILTIN or '=' in line.split(None, 1)[1].split('#')[0]:
            continue
        out.append(kind if '/' in kind else f'{package}/{kind}')
    return out


def message_definition(type_name: str) -> str:
    """rosbag2's ``ros2msg`` schema text of ``pkg/msg/Type``: its ``.msg``, then each nested
    type once (``MSG: pkg/Type`` after a line of 80 ``=``)."""
    package, _, name = type_name.split('/')
    root = _msg_file(package, name).read_text()
    parts, seen, todo = [root], set(), _field_types(root, package)
    while todo:
        dep = todo.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        dep_package, dep_name = dep.split('/')[0], dep.split('/')[-1]
        text = _msg_file(dep_package, dep_name).read_text()
        parts.append(f'{_SEPARATOR}\nMSG: {dep_package}/{dep_name}\n{text}')
        todo += _field_types(text, dep_package)
    return '\n'.join(parts)


def _type_name(msg) -> str:
    """``pkg/msg/Type`` of a message instance."""
    module = type(msg).__module__.split('.')
    return f'{module[0]}/msg/{type(msg).__name__}'


def attack_messages(scene: Scene, boxes: tuple[SceneObject, ...] | list[SceneObject],
                    heatmap=None) -> list[tuple[str, object]]:
    """(topic, message) in publishing order: the scene, its goal region, a sensed cloud, one
    ADD per box in pick order, the markers (boxes and scene), the heatmap's hottest voxels."""
    from advocc_ros.ros.clouds import CLOUD_TOPIC, cloud_msg, markers_with_scene, scene_cloud
    from advocc_ros.ros.conversions import (box_markers, collision_object_to_msg,
                                            goal_region_to_msg, scene_to_msg)
    from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, SCENE_TOPIC

    frame = scene.frame
    out: list[tuple[str, object]] = [(SCENE_TOPIC, scene_to_msg(scene))]
    if scene.goal is not None:
        out.append((GOAL_REGION_TOPIC, goal_region_to_msg(scene.goal, frame)))
    cloud = scene_cloud(scene.objects)
    if cloud is not None:
        out.append((CLOUD_TOPIC, cloud_msg(cloud[0], frame)))
    out += [(COLLISION_OBJECT_TOPIC, collision_object_to_msg(box, frame, Operation.ADD))
            for box in boxes]
    out.append((SCENE_MARKERS_TOPIC, markers_with_scene(
        box_markers(tuple(boxes), frame, 'advocc_attack'), scene.objects, frame,
        'advocc_scene')))
    if heatmap is not None:
        from advocc_ros.heatmap import hottest_voxels

        points, H = hottest_voxels(heatmap, HEATMAP_PERCENTILE)
        out.append((HEATMAP_TOPIC, cloud_msg(points, frame, H)))
    return out


def write_bag(path: str | pathlib.Path, messages: list[tuple[str, object]],
              stamp_ns: int | None = None) -> pathlib.Path:
    """Write ``messages`` ((topic, message), in order, 1 ms apart from ``stamp_ns``) into one
    MCAP file; headers get the stamps. Returns the path."""
    path = pathlib.Path(path)
    if path.suffix != '.mcap':
        raise ValueError(f'{path}: a bag file must end in .mcap')
    start_ns = time.time_ns() if stamp_ns is None else int(stamp_ns)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.name}.tmp')
    with open(tmp, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='advocc_ros (mcap)')
        schemas, channels = {}, {}
        for k, (topic, msg) in enumerate(messages):
            stamp = start_ns + k * 1_000_000
            stamp_message(msg, stamp)
            type_name = _type_name(msg)
            if type_name not in schemas:
                schemas[type_name] = writer.register_schema(
                    type_name, 'ros2msg', message_definition(type_name).encode())
            if topic not in channels:
                channels[topic] = writer.register_channel(
                    topic, 'cdr', schemas[type_name], {'offered_qos_profiles': _LATCHED_QOS_YAML})
            writer.add_message(channels[topic], stamp, serialize_message(msg), stamp, k)
        writer.finish()
    os.replace(tmp, path)
    return path


def stamp_message(msg, stamp_ns: int) -> None:
    """Set the header stamp of ``msg`` and of its markers."""
    for item in [msg] + list(getattr(msg, 'markers', [])):
        header = getattr(item, 'header', None)
        if header is not None:
            header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)


def write_attack_bag(path: str | pathlib.Path, scene: Scene,
                     boxes: tuple[SceneObject, ...] | list[SceneObject], heatmap=None
                     ) -> pathlib.Path:
    """The bag of one attack (see :func:`attack_messages`)."""
    return write_bag(path, attack_messages(scene, boxes, heatmap))
