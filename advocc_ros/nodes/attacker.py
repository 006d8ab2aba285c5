"""attacker: keeps the adversarial boxes of the current task in the planning scene.

Subscribes (latched QoS, so a late joiner gets the last ones) to ``/advocc/scene``
(advocc_msgs/Scene: static objects + start state) and ``/advocc/goal_region``
(advocc_msgs/GoalRegion). When both are known, and whenever either changes, it calls the
heatmap server's ``~/attack`` (``call_async``; one request in flight, and messages that arrive
meanwhile coalesce into one more request with the latest task), then

- publishes REMOVE for each box it placed before and ADD for the new ones on
  ``/advocc/collision_object`` (advocc_msgs/CollisionObject, MoveIt semantics), and
- publishes a ``visualization_msgs/MarkerArray`` on ``~/markers`` (DELETEALL + one red cube
  per box, then the scene's objects in grey and the sensed cloud's octree leaves in blue).

The sensed part of the scene arrives on ``/advocc/cloud`` (sensor_msgs/PointCloud2, latched, xyz
in the robot base frame): cropped to ``cloud_crop_min/max`` and sent with every request as an
octree of ``cloud_resolution``, as MoveIt's occupancy-map updater feeds its octomap.

A failed attack (error code) or a timeout removes the previous boxes, which no longer match the
task. Parameters: :data:`PARAMETERS` (``ros2 param describe /attacker <name>``; the same
defaults in ``config/attacker.yaml``); with ``bag`` (a ``.mcap`` file) each attack's scene, goal
region, boxes, markers and the server's heatmap cloud are recorded there as a ROS 2 bag,
replacing the last one.
"""

from __future__ import annotations

import sys
import time

from advocc_msgs.msg import CollisionObject, ErrorCodes, GoalRegion, Scene
from advocc_msgs.srv import Attack
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from advocc_ros.attack.methods import SERVER_METHODS
from advocc_ros.attack.types import DEFAULT_METHOD, POLICIES, AttackConfig
from advocc_ros.model.scene import Operation, SceneObject
from advocc_ros.model.pose import SceneError
from advocc_ros.nodes import run
from advocc_ros.ros.clouds import (CLOUD_PARAMETERS, CLOUD_TOPIC, cloud_msg,
                                   cloud_shape_from_node_params, markers_with_scene)
from advocc_ros.ros.conversions import (attack_request_from_msgs, box_markers,
                                        collision_object_to_msg, obstacles_from_msgs,
                                        scene_from_msgs)
from advocc_ros.ros.params import INT_MAX, Param, declare
from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, LATCHED_QOS, SCENE_TOPIC

MARKER_NS = 'advocc_attack'
PARAMETERS = (
    Param('server', '/heatmap_server', 'heatmap_server node whose ~/attack is called',
          read_only=True),
    Param('budget', 3, 'M, boxes per attack', low=1, high=AttackConfig.max_budget),
    Param('method', DEFAULT_METHOD, 'attack method', constraints=f'one of {list(SERVER_METHODS)} '
          '(the methods a heatmap server runs without planner queries)'),
    Param('box_size_m', 0.0, "box edge [m]; 0: the server's default",
          low=0.0, high=AttackConfig.max_box_m),
    Param('seed', 0, 'seed of the seeded methods (random, task)', low=-INT_MAX, high=INT_MAX),
    Param('goal_policy', '', "goal policy of the requests; '': the server's default",
          constraints=f"one of {list(POLICIES)} or ''"),
    Param('timeout_s', 180.0, 'a request without answer after this is dropped [s] (the first '
          "solvable attack of a task includes its witness searches and judging goal set: "
          "69 s measured with the witnesses cached)", low=0.0, high=3600.0),
    Param('bag', '', "a .mcap file each attack is recorded to as a ROS 2 bag ('': none)"),
    *CLOUD_PARAMETERS)
"""The attacker's parameters: what ``config/attacker.yaml`` sets, with their descriptors."""


class Attacker(Node):
    """Scene + goal in, adversarial collision objects and markers out."""

    def __init__(self):
        super().__init__('attacker')
        self._scene: Scene | None = None
        self._goal: GoalRegion | None = None
        self._dirty = False          # the task changed since the last request was sent
        self.add_on_set_parameters_callback(self._check_parameters)  # checks overrides too
        declare(self, PARAMETERS)

        server = self.get_parameter('server').value.rstrip('/')
        self._client = self.create_client(Attack, f'{server}/attack')
        self._objects_pub = self.create_publisher(CollisionObject, COLLISION_OBJECT_TOPIC,
                                                  LATCHED_QOS)
        self._markers_pub = self.create_publisher(MarkerArray, '~/markers', LATCHED_QOS)
        self.create_subscription(Scene, SCENE_TOPIC, self._on_scene, LATCHED_QOS)
        self.create_subscription(GoalRegion, GOAL_REGION_TOPIC, self._on_goal, LATCHED_QOS)
        self.create_subscription(PointCloud2, CLOUD_TOPIC, self._on_cloud, LATCHED_QOS)
        self._heatmap_msg = None  # the server's hottest voxels, for the bag
        self.create_subscription(PointCloud2, f'{server}/heatmap',
                                 lambda msg: setattr(self, '_heatmap_msg', msg), LATCHED_QOS)
        self._cloud: SceneObject | None = None  # the sensed part of the scene
        self._future = None          # request in flight
        self._sent_at = 0.0
        self._placed: list[str] = []  # ids of our boxes in the planning scene
        self._frame = ''              # the robot base frame, as the scene names it
        self._early_cloud: PointCloud2 | None = None  # came before the scene: checked then
        self._attacks = 0
        self._waiting_logged = False
        self.create_timer(0.1, self._tick)

    def _check_parameters(self, params) -> SetParametersResult:
        """The method's name (ranges and read-only are the descriptors', checked by rclpy)."""
        for p in params:
            if p.name == 'method' and p.value not in SERVER_METHODS:
                return SetParametersResult(
                    successful=False, reason=f'method {p.value!r}: expected one of '
                    f'{list(SERVER_METHODS)} (the methods a heatmap server runs)')
            if p.name == 'goal_policy' and p.value not in ('', *POLICIES):
                return SetParametersResult(
                    successful=False, reason=f'goal_policy {p.value!r}: expected one of '
                    f"{list(POLICIES)} or '' (the server's default)")
        if any(p.name in ('budget', 'method', 'box_size_m', 'seed', 'goal_policy')
               for p in params):
            self._dirty = self._scene is not None and self._goal is not None
        return SetParametersResult(successful=True)

    # -- inputs ------------------------------------------------------------------------------

    def _on_scene(self, msg: Scene) -> None:
        self._scene = msg
        self._frame = msg.header.frame_id or self._frame
        self._dirty = True
        self.get_logger().info(f'scene {msg.name!r}: {len(msg.objects)} objects')
        if self._early_cloud is not None:
            cloud, self._early_cloud = self._early_cloud, None
            self._on_cloud(cloud)
        self._tick()

    def _on_cloud(self, msg: PointCloud2) -> None:
        if self._scene is None:  # the cloud is latched: keep it until we know the base frame
            self._early_cloud = msg
            self.get_logger().info('cloud received before the scene: checked when it comes')
            return
        try:
            frame = msg.header.frame_id
            if frame and self._frame and frame != self._frame:
                raise SceneError(f'frame {frame!r} is not the robot base frame {self._frame!r}')
            shape = cloud_shape_from_node_params(self, msg)
            self._cloud = None if shape is None else SceneObject('sensed_cloud', (shape,))
            self._dirty = True
            self.get_logger().info(f'cloud: {msg.width * msg.height} points, '
                                   f'{0 if shape is None else len(shape.vertices)} in the box')
            self._tick()
        except (SceneError, ValueError) as exc:
            self.get_logger().error(f'cloud rejected: {exc}')

    def _on_goal(self, msg: GoalRegion) -> None:
        self._goal = msg
        self._dirty = True
        self.get_logger().info('goal region received')
        self._tick()

    # -- requests ----------------------------------------------------------------------------

    def _tick(self) -> None:
        """Send one request when the task changed and none is in flight; watch timeouts."""
        try:
            if self._future is not None:
                if time.monotonic() - self._sent_at > self.get_parameter('timeout_s').value:
                    self._client.remove_pending_request(self._future)
                    self._future = None
                    self.get_logger().error('attack request timed out; removing old boxes')
                    self._publish([])
                    self._dirty = True  # try again
                return
            if not self._dirty or self._scene is None or self._goal is None:
                return
            if not self._client.service_is_ready():
                if not self._waiting_logged:
                    self.get_logger().info(f'waiting for {self._client.srv_name}')
                    self._waiting_logged = True
                return
            req = attack_request_from_msgs(
                self._scene, self._goal, self.get_parameter('budget').value,
                self.get_parameter('method').value, self.get_parameter('box_size_m').value,
                self.get_parameter('seed').value, self.get_parameter('goal_policy').value)
            if self._cloud is not None:
                shape = self._cloud.shapes[0]
                req.cloud = cloud_msg(shape.vertices, self._frame)
                req.cloud_resolution = float(shape.dims[0])
            self._dirty = False
            self._sent_at = time.monotonic()
            self._future = self._client.call_async(req)
            self._future.add_done_callback(self._on_response)
        except Exception as exc:  # never let a callback take the executor down
            self.get_logger().error(f'attack request failed: {exc!r}')

    def _on_response(self, future) -> None:
        try:
            if future is not self._future:  # timed out and superseded
                return
            self._future = None
            res = future.result()
            self._attacks += 1
            if res.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL):
                self._publish(list(res.obstacles))
                self.get_logger().info(
                    f'attack #{self._attacks}: {len(res.obstacles)} boxes, mass '
                    f'{res.total_mass:.3f}, {res.compute_time_s * 1e3:.1f} ms ({res.message}); '
                    f'solvable: {res.solvable or "not assessed"}')
            else:
                self._publish([])
                self.get_logger().error(
                    f'attack #{self._attacks} failed: {res.error_code.val} {res.message}')
        except Exception as exc:
            self.get_logger().error(f'attack response failed: {exc!r}')
        self._tick()  # the task may have changed while the request was in flight

    # -- outputs -----------------------------------------------------------------------------

    def _publish(self, obstacles: list) -> None:
        """REMOVE our previous boxes, ADD the new ones (``Obstacle`` messages), and replace
        the markers."""
        boxes = obstacles_from_msgs(obstacles)
        msgs = [collision_object_to_msg(SceneObject(obj_id, ()), self._frame, Operation.REMOVE)
                for obj_id in self._placed]
        msgs += [collision_object_to_msg(box, self._frame, Operation.ADD) for box in boxes]
        for msg in msgs:
            msg.header.stamp = self.get_clock().now().to_msg()
            self._objects_pub.publish(msg)
        objects = scene_from_msgs(list(self._scene.objects)) if self._scene else ()
        objects += (self._cloud,) if self._cloud is not None else ()
        markers = markers_with_scene(box_markers(boxes, self._frame, MARKER_NS), objects,
                                     self._frame, 'advocc_scene')
        self._markers_pub.publish(markers)
        self._placed = [box.id for box in boxes]
        if self.get_parameter('bag').value and boxes:
            self._record(msgs[len(msgs) - len(boxes):], markers)

    def _record(self, adds: list, markers) -> None:
        """Write this attack's bag (see the module docstring); a failure is logged only."""
        from advocc_ros.ros.bag import HEATMAP_TOPIC, SCENE_MARKERS_TOPIC, write_bag

        path = self.get_parameter('bag').value
        messages = [(SCENE_TOPIC, self._scene), (GOAL_REGION_TOPIC, self._goal)]
        if self._cloud is not None:
            messages.append((CLOUD_TOPIC, cloud_msg(self._cloud.shapes[0].vertices,
                                                    self._frame)))
        messages += [(COLLISION_OBJECT_TOPIC, m) for m in adds]
        messages.append((SCENE_MARKERS_TOPIC, markers))
        if self._heatmap_msg is not None:
            messages.append((HEATMAP_TOPIC, self._heatmap_msg))
        try:
            write_bag(path, messages)
            self.get_logger().info(f'bag: {path} ({len(messages)} messages)')
        except (OSError, ValueError) as exc:
            self.get_logger().error(f'bag {path!r} not written: {exc}')


def main(args=None) -> int:
    return run(Attacker, 'attacker', args)


if __name__ == '__main__':
    sys.exit(main())
