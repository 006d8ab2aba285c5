"""planner_shim: a MoveIt move_group stand-in that plans with OMPL in an attackable scene.

Planning scene = the static scene of the ``scene_file`` parameter + objects injected on
``/advocc/collision_object`` (MoveIt ADD/REMOVE/APPEND/MOVE semantics; latched QoS so a late
joiner still receives an attack's operations). Injected operations never touch the static
objects: a REMOVE with an empty id clears the injected objects only, and an id that names a
static object is rejected, so an attacker can reset its boxes without deleting the table.

The sensed part of the scene arrives on ``/advocc/cloud`` (sensor_msgs/PointCloud2, latched,
xyz in the planning frame): cropped to ``cloud_crop_min/max``, it becomes one octree object
(``cloud_resolution``) that each new cloud replaces, as in MoveIt's occupancy-map updater.

Services:
- ``~/plan`` (advocc_msgs/srv/Plan): start state, goal region, planner id, budget, seed ->
  MoveIt error code + message + trajectory + planning time. A task whose start is outside the
  joint limits or in collision (self or with the current scene) is refused before planning with
  the reason (``model.task_check``: the joint, or the colliding pair). Requests run in a
  watched worker process (``advocc_ros.planning.worker.Planner``): a request never holds the
  node longer than its budget + ``watchdog_margin_s``; bad requests get an error code and the
  node keeps serving.
- ``~/get_info`` (advocc_msgs/srv/GetInfo): what is loaded, as JSON.

Backends (``backend``, read-only): ``ompl`` (default) serves a request's ``planner_id`` with our
OMPL planners, or with the outside victim of that name (``mplib``; created on first use); an
outside victim's name (``backend:=mplib``) serves every request with that victim, whatever the
``planner_id``, so the orchestrator benchmarks a planner we did not write through ROS exactly
like ours (``advocc_ros.planning.victims``; docs/transfer.md).

Parameters: :data:`PARAMETERS` (the same defaults in ``config/planner_shim.yaml``;
``ros2 param describe``).

The plan service has its own callback group and the node spins a MultiThreadedExecutor, so
collision objects keep arriving while a request is being planned (the next request sees them).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import threading

from advocc_msgs.msg import CollisionObject, ErrorCodes
from advocc_msgs.srv import GetInfo, Plan
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from advocc_ros.ros.conversions import (collision_object_from_msg, goal_region_from_msg,
                                        q_from_joint_state, trajectory_to_msg)
from advocc_ros.nodes import run
from advocc_ros.ros.clouds import CLOUD_PARAMETERS, CLOUD_TOPIC, cloud_shape_from_node_params
from advocc_ros.ros.params import INT_MAX, Param, declare
from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, LATCHED_QOS
from advocc_ros.paths import allowed_dirs, confine, scene_path
from advocc_ros.planning.types import PLANNERS, PlanningConfig, PlanStatus
from advocc_ros.planning.worker import Planner
from advocc_ros.planning.victims import (Task, VictimConfig, is_outside, is_victim, make_victim,
                                         victim_names)
from advocc_ros.model.robot import RobotError, resolve_path
from advocc_ros.model.task_check import TaskProblem, check_task
from advocc_ros.model.scene import (Scene, SceneObject, apply_operation, load_scene,
                                    referenced_files)
from advocc_ros.model.pose import SceneError

# Parameters that map onto PlanningConfig fields (defaults come from the dataclass): their
# description, and the closed range when PlanningConfig's check is one.
_CONFIG_DOC = {
    'time_budget_s': ("used when a request's time_budget_s is 0 [s]; <= max_time_budget_s",
                      None),
    'max_time_budget_s': ('larger budgets are rejected [s]', None),
    'motion_step_rad': ('joint-space distance between validity checks [rad]', None),
    'ik_goals': ('goal configurations sampled by IK before planning', (1, INT_MAX)),
    'max_goals': ('cap on goal configurations, lazily sampled ones included', (1, INT_MAX)),
    'simplify': ('MoveIt-style shortcut + smoothing', None),
    'interpolate': ('waypoints at most waypoint_step_rad apart', None),
    'waypoint_step_rad': ('largest joint-space distance between returned waypoints [rad]',
                          None),
    'stop_at_first_solution': ('PRM*/RRT*: return the first solution instead of optimizing '
                               'until the budget ends', None),
    'watchdog_margin_s': ('the planning worker is killed after budget + margin [s]', None),
}
_CONFIG_PARAMS = tuple(_CONFIG_DOC)
_TASK_STATUS = {TaskProblem.START_INVALID: PlanStatus.INVALID_ROBOT_STATE,
                TaskProblem.START_IN_COLLISION: PlanStatus.START_STATE_IN_COLLISION,
                TaskProblem.GOAL_INVALID: PlanStatus.INVALID_GOAL_CONSTRAINTS,
                TaskProblem.GOAL_IN_COLLISION: PlanStatus.GOAL_IN_COLLISION}


def _config_param(name: str) -> Param:
    description, limits = _CONFIG_DOC[name]
    default = getattr(PlanningConfig(), name)
    if limits is None:
        return Param(name, default, description,
                     constraints='> 0' if isinstance(default, float) else '')
    return Param(name, default, description, low=limits[0], high=limits[1])


PARAMETERS = (
    Param('scene_file', 'table_pick', 'static scene: a scene YAML path or a shipped scene name',
          read_only=True),
    Param('default_planner', 'rrtconnect', "used when a request's planner_id is empty",
          constraints='an OMPL geometric planner id (advocc_ros.planning.PLANNERS) or an '
                      'outside victim (mplib)'),
    Param('backend', 'ompl', 'ompl: planner_id picks an OMPL planner or an outside victim; '
          'an outside victim name (mplib): it serves every request', read_only=True,
          constraints='ompl | ' + ' | '.join(victim_names())),
    Param('allowed_dirs', [''], "directories the node may read files from (['']: the "
          'defaults, see README "Security")', read_only=True),
    *CLOUD_PARAMETERS,
    *(_config_param(name) for name in _CONFIG_PARAMS))
"""The shim's parameters, with their descriptors."""


class PlannerShim(Node):
    """Planning scene + plan service (see the module docstring)."""

    def __init__(self):
        super().__init__('planner_shim')
        self.add_on_set_parameters_callback(self._check_parameters)  # checks overrides too
        declare(self, PARAMETERS)

        scene_arg = self.get_parameter('scene_file').value
        allowed = allowed_dirs(self.get_parameter('allowed_dirs').value)
        if scene_arg:
            scene_file = confine(scene_path(scene_arg), allowed, 'scene_file')
            for file in referenced_files(scene_file):  # meshes and clouds follow the same rule
                confine(file, allowed, 'scene_file object file')
            self._static: Scene = load_scene(scene_file)
            for field in ('urdf', 'srdf'):  # a scene file names the robot files to read
                confine(resolve_path(getattr(self._static.robot, field)),
                        allowed + [resolve_path('example-robot-data://')],
                        f'scene_file robot.{field}')
        else:
            self._static = Scene()
        self._injected: dict = {}
        self._sensed: tuple[SceneObject, ...] = ()  # the cloud of /advocc/cloud
        self._scene_lock = threading.Lock()
        self._planner = Planner(self._static, self._config())
        self._planner.start()
        self._victims: dict = {}
        backend = self.get_parameter('backend').value
        if backend != 'ompl':
            if not is_outside(backend):
                raise ValueError(f'backend {backend!r}: expected ompl or one of '
                                 f'{victim_names()}')
            self._victim(backend, self._config())  # start it now: a missing venv fails here
        self._served = 0
        self.get_logger().info(
            f'scene {self._static.name!r} ({len(self._static.objects)} static objects), '
            f'planning worker pid {self._planner.worker_pid}')

        scene_group = MutuallyExclusiveCallbackGroup()
        self.create_subscription(CollisionObject, COLLISION_OBJECT_TOPIC, self._on_object,
                                 LATCHED_QOS, callback_group=scene_group)
        self.create_subscription(PointCloud2, CLOUD_TOPIC, self._on_cloud, LATCHED_QOS,
                                 callback_group=scene_group)
        self.create_service(GetInfo, '~/get_info', self._on_get_info,
                            callback_group=scene_group)
        self.create_service(Plan, '~/plan', self._on_plan,
                            callback_group=MutuallyExclusiveCallbackGroup())

    # -- parameters --------------------------------------------------------------------------

    def _config(self) -> PlanningConfig:
        values = {name: self.get_parameter(name).value for name in _CONFIG_PARAMS}
        return dataclasses.replace(PlanningConfig(), **values)

    def _check_parameters(self, params) -> SetParametersResult:
        """Planner names here; the planning values together are PlanningConfig's to check (its
        ValueError is the reason). Ranges and read-only are the descriptors', checked by rclpy.
        """
        for p in params:
            if p.name == 'default_planner' and not is_victim(p.value):
                return SetParametersResult(successful=False,
                                           reason=f'unknown planner {p.value!r}')
        changes = {p.name: p.value for p in params if p.name in _CONFIG_PARAMS}
        if changes:
            current = {name: self.get_parameter(name).value for name in _CONFIG_PARAMS
                       if self.has_parameter(name)}
            try:
                PlanningConfig(**{**current, **changes})
            except (TypeError, ValueError) as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    # -- planning scene ----------------------------------------------------------------------

    def _scene(self) -> Scene:
        with self._scene_lock:
            return self._static.with_objects(list(self._injected.values()) + list(self._sensed))

    def _on_cloud(self, msg: PointCloud2) -> None:
        try:
            frame = msg.header.frame_id
            if frame and frame != self._static.frame:
                raise SceneError(f'frame {frame!r} is not the planning frame '
                                 f'{self._static.frame!r} (no tf here)')
            shape = cloud_shape_from_node_params(self, msg)
            with self._scene_lock:
                self._sensed = () if shape is None else (SceneObject('sensed_cloud', (shape,)),)
            self.get_logger().info(f'cloud: {msg.width * msg.height} points, '
                                   f'{0 if shape is None else len(shape.vertices)} in the box')
        except (SceneError, ValueError) as exc:
            self.get_logger().error(f'cloud rejected: {exc}')

    def _on_object(self, msg: CollisionObject) -> None:
        try:
            frame = msg.header.frame_id
            if frame and frame != self._static.frame:
                raise SceneError(f'frame {frame!r} is not the planning frame '
                                 f'{self._static.frame!r} (no tf here)')
            op, obj, pose = collision_object_from_msg(msg, 'collision object')
            if obj.id in {o.id for o in self._static.objects}:
                raise SceneError(f'id {obj.id!r} names a static scene object')
            with self._scene_lock:
                self._injected = apply_operation(self._injected, op, obj, pose)
                count = len(self._injected)
            self.get_logger().info(f'collision object {msg.id!r} op {op}: '
                                   f'{count} injected objects')
        except (SceneError, RobotError, ValueError) as exc:
            self.get_logger().error(f'collision object rejected: {exc}')

    # -- services ----------------------------------------------------------------------------

    def _on_plan(self, request: Plan.Request, response: Plan.Response) -> Plan.Response:
        try:
            response = self._plan(request, response)
        except Exception as exc:  # never let a callback take the executor down
            self.get_logger().error(f'plan request failed: {exc!r}')
            response.error_code.val = int(PlanStatus.INTERNAL_ERROR)
            response.message = f'internal error: {exc!r}'
        self._served += 1
        text = f'plan #{self._served}: {response.error_code.val} {response.message}'
        # One call site per severity: rclpy refuses a call site whose severity changes.
        if response.error_code.val == ErrorCodes.SUCCESS:
            self.get_logger().info(text)
        else:
            self.get_logger().warning(text)
        return response

    def _plan(self, request: Plan.Request, response: Plan.Response) -> Plan.Response:
        def fail(status: PlanStatus, message: str) -> Plan.Response:
            response.error_code.val = int(status)
            response.message = message
            return response

        robot = self._planner.robot
        if not all(math.isfinite(v) for v in request.start_state.position):
            return fail(PlanStatus.INVALID_REQUEST, 'start_state: non-finite joint positions')
        try:
            q_start = q_from_joint_state(robot, request.start_state)
        except RobotError as exc:
            return fail(PlanStatus.INVALID_ROBOT_STATE, str(exc))
        gmsg = request.goal_region
        numbers = [gmsg.center.position.x, gmsg.center.position.y, gmsg.center.position.z,
                   gmsg.center.orientation.x, gmsg.center.orientation.y,
                   gmsg.center.orientation.z, gmsg.center.orientation.w,
                   *gmsg.position_tolerance, *gmsg.orientation_tolerance]
        if not all(math.isfinite(v) for v in numbers):
            return fail(PlanStatus.INVALID_REQUEST, 'goal_region: non-finite values')
        frame = gmsg.header.frame_id
        if frame and frame != self._static.frame:
            return fail(PlanStatus.INVALID_GOAL_CONSTRAINTS,
                        f'goal_region frame {frame!r} is not the planning frame '
                        f'{self._static.frame!r}')
        try:
            goal = goal_region_from_msg(gmsg, robot.spec.ee_link)
        except SceneError as exc:
            return fail(PlanStatus.INVALID_GOAL_CONSTRAINTS, str(exc))
        budget = request.time_budget_s
        if not math.isfinite(budget) or budget < 0:
            return fail(PlanStatus.INVALID_REQUEST,
                        f'time_budget_s must be >= 0 (0: default), got {budget}')
        scene = self._scene()
        fault = check_task(robot, scene.objects, q_start, goal)
        if fault is not None:  # a wrong task, not a planner outcome: refused with the reason
            return fail(_TASK_STATUS[fault.problem], fault.message)
        config = self._config()
        budget = budget or config.time_budget_s
        planner_id = request.planner_id or self.get_parameter('default_planner').value
        backend = self.get_parameter('backend').value
        name = planner_id if backend == 'ompl' else backend
        if is_outside(name):
            task = Task(scene, q_start, goal)
            result = self._victim(name, config).plan(task, budget, request.seed)
        else:
            self._planner.config = config
            self._planner.set_scene(scene)
            result = self._planner.plan(q_start, goal, planner_id, budget, request.seed)
        response.error_code.val = int(result.status)
        response.message = result.message
        response.planning_time_s = float(result.planning_time_s)
        if result.success:
            response.first_solution_s = result.first_solution_s
            response.trajectory = trajectory_to_msg(robot, result.path)
            response.trajectory.header.frame_id = self._static.frame
        return response

    def _victim(self, name: str, config: PlanningConfig):
        """The outside victim ``name`` (started on first use) with the current settings."""
        victim = self._victims.get(name)
        if victim is None:
            victim = self._victims[name] = make_victim(name, VictimConfig(planning=config))
            victim.start(self._static)
            self.get_logger().info(f'outside victim {name!r} started')
        victim.config = VictimConfig(planning=config)
        return victim

    def _on_get_info(self, request: GetInfo.Request, response: GetInfo.Response
                     ) -> GetInfo.Response:
        try:
            with self._scene_lock:
                injected = sorted(self._injected)
                sensed = {o.id: len(o.shapes[0].vertices) for o in self._sensed}
            robot = self._planner.robot
            info = {
                'node': self.get_fully_qualified_name(),
                'scene': self._static.name, 'frame': self._static.frame,
                'scene_file': self.get_parameter('scene_file').value,
                'static_objects': [o.id for o in self._static.objects],
                'injected_objects': injected,
                'sensed_points': sensed,
                'robot': {'joints': list(robot.joint_names), 'ee_link': robot.spec.ee_link,
                          'hash': robot.hash},
                'planners': sorted(PLANNERS) + victim_names(),
                'backend': self.get_parameter('backend').value,
                'victims_started': sorted(self._victims),
                'default_planner': self.get_parameter('default_planner').value,
                'config': dataclasses.asdict(self._config()),
                'worker_pid': self._planner.worker_pid,
                'worker_restarts': self._planner.restarts,
                'requests_served': self._served,
            }
            response.success = True
            response.info_json = json.dumps(info)
            response.message = 'ok'
        except Exception as exc:
            response.success = False
            response.message = f'internal error: {exc}'
        return response

    def destroy_node(self):
        planner = getattr(self, '_planner', None)
        if planner is not None:
            planner.close()
        for victim in getattr(self, '_victims', {}).values():
            victim.close()
        return super().destroy_node()


def main(args=None) -> int:
    return run(PlannerShim, 'planner_shim', args,
               startup_errors=(SceneError, RobotError, ValueError), threads=3)


if __name__ == '__main__':
    sys.exit(main())
