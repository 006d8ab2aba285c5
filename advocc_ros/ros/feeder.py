"""The online attack through the ROS graph, for ``advocc demo``.

:func:`run_attack_nodes` starts ``heatmap_server`` and ``attacker`` as child processes on a
private ROS domain, publishes the scene and goal region on their latched topics, collects the
boxes the attacker adds on ``/advocc/collision_object``, writes them as an obstacles file, and
always stops the children.
"""

from __future__ import annotations

import os
import pathlib
import tempfile
import time

from advocc_ros.attack.obstacles import obstacles_file_data, save_obstacles
from advocc_ros.attack.types import DEFAULT_METHOD
from advocc_ros.model.scene import Scene
from advocc_ros.ros.spawn import start_node, stop


def run_attack_nodes(heatmap_file: str | pathlib.Path, scene: Scene, out: str | pathlib.Path,
                     budget: int = 3, method: str = DEFAULT_METHOD, timeout_s: float = 90.0,
                     domain: int | None = None, bag: str | pathlib.Path | None = None) -> dict:
    """Attack ``scene``'s task through the nodes; returns what the attacker published
    (``bag``: the attacker records the attack there as a ROS 2 bag, ``.mcap``).

    Raises ``RuntimeError`` (with the nodes' output) if no boxes arrive within ``timeout_s``.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from advocc_ros.ros.clouds import scene_cloud
    from advocc_ros.ros.conversions import collision_object_from_msg

    if scene.start is None or scene.goal is None:
        raise ValueError(f'scene {scene.name!r} needs a start and a goal')
    domain = 150 + os.getpid() % 80 if domain is None else domain
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1')
    logs = [tempfile.TemporaryFile(mode='w+') for _ in range(2)]
    cloud = scene_cloud(scene.objects)
    attacker_params = {'budget': int(budget), 'method': method}
    if cloud is not None:
        attacker_params['cloud_resolution'] = float(cloud[1])
    if bag is not None:
        attacker_params['bag'] = str(pathlib.Path(bag).resolve())
    procs = [start_node('heatmap_server', {'heatmap_file': heatmap_file}, env=env, log=logs[0]),
             start_node('attacker', attacker_params, env=env, log=logs[1])]
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('advocc_demo_feeder', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    added: list = []
    try:
        _feed_task(node, scene, cloud, added)
        elapsed = _wait_for_boxes(executor, procs, added, budget, timeout_s, bag)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        codes = [stop(p) for p in procs]
    output = []
    for log in logs:
        log.seek(0)
        output.append(log.read())
        log.close()
    if not added:
        raise RuntimeError('the attacker published no boxes within '
                           f'{timeout_s:g} s\n--- heatmap_server:\n{output[0]}\n'
                           f'--- attacker:\n{output[1]}')
    boxes = [collision_object_from_msg(m, 'attacker box')[1] for m in added]
    data = obstacles_file_data(
        boxes, method, budget, scene={'name': scene.name, 'objects_hash': scene.objects_hash()},
        extra={'source': 'heatmap_server + attacker nodes', 'heatmap_file': str(heatmap_file)})
    save_obstacles(out, data)
    return {'obstacles': data['objects'], 'seconds_to_boxes': round(elapsed, 3),
            'exit_codes': {'heatmap_server': codes[0], 'attacker': codes[1]},
            'out': str(out), 'logs': {'heatmap_server': output[0], 'attacker': output[1]}}


def _feed_task(node, scene: Scene, cloud, added: list) -> None:
    """Subscribe ``added`` to the boxes the attacker adds, then publish the task on the latched
    topics the attacker listens to: the sensed cloud (if the scene has one), the scene and the
    goal region."""
    from advocc_msgs.msg import CollisionObject, GoalRegion, Scene as SceneMsg
    from sensor_msgs.msg import PointCloud2

    from advocc_ros.ros.clouds import CLOUD_TOPIC, cloud_msg
    from advocc_ros.ros.conversions import goal_region_to_msg, scene_to_msg
    from advocc_ros.ros.qos import (COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, LATCHED_QOS,
                                    SCENE_TOPIC)

    node.create_subscription(
        CollisionObject, COLLISION_OBJECT_TOPIC,
        lambda m: added.append(m) if m.operation == CollisionObject.ADD else None,
        LATCHED_QOS)
    if cloud is not None:
        node.create_publisher(PointCloud2, CLOUD_TOPIC, LATCHED_QOS).publish(
            cloud_msg(cloud[0], scene.frame))
    node.create_publisher(SceneMsg, SCENE_TOPIC, LATCHED_QOS).publish(scene_to_msg(scene))
    node.create_publisher(GoalRegion, GOAL_REGION_TOPIC, LATCHED_QOS).publish(
        goal_region_to_msg(scene.goal, scene.frame))


def _wait_for_boxes(executor, procs, added: list, budget: int, timeout_s: float,
                    bag: str | pathlib.Path | None) -> float:
    """Spin until ``budget`` boxes arrived in ``added``, a node exited or ``timeout_s`` passed,
    then briefly for late boxes and for the attacker's bag; seconds until the boxes."""
    t0 = time.monotonic()
    while len(added) < budget:
        if any(p.poll() is not None for p in procs) or time.monotonic() - t0 > timeout_s:
            break
        executor.spin_once(timeout_sec=0.1)
    # A PARTIAL attack adds fewer boxes: give late ones a moment.
    settle = time.monotonic() + (0.5 if len(added) >= budget else 2.0)
    while time.monotonic() < settle and len(added) < budget:
        executor.spin_once(timeout_sec=0.1)
    written = time.monotonic() + 5.0  # the attacker writes its bag after publishing
    while bag is not None and not pathlib.Path(bag).is_file() and time.monotonic() < written:
        executor.spin_once(timeout_sec=0.1)
    return time.monotonic() - t0
