"""heatmap_server: answers online attack requests from a heatmap loaded at start-up.

Parameters: :data:`PARAMETERS` (defaults = ``advocc_ros.attack.AttackConfig`` and
``RobotSpec``, the same in ``config/heatmap_server.yaml``; ``ros2 param describe``):
``heatmap_file`` (required), the attack parameters, the ``task`` method's options
(``task_<option>``: ``advocc_ros.attack.task.TaskOptions``, e.g. ``task_tube_samples:=512``),
the robot description and ``base_frame``.
The values of joints outside the planning group (locked at the task's robot state, see
``docs/design.md``) come from ``robot_locked`` (``['joint=value', ...]``) or else from the
heatmap file, which records the robot it was built for (a heatmap of a Panda with open fingers
serves with open fingers). A heatmap that cannot be loaded, or was built for another robot,
stops the node at start-up with a clear message and exit code 1.

Services:
- ``~/attack`` (advocc_msgs/srv/Attack): scene objects, start state, goal region, budget,
  method, box size, seed -> error code (MoveIt values + advocc's own) + message + obstacles +
  covered mass + compute time. Every bad request gets a code and a message (a task whose start
  is outside the joint limits or in collision: the joint or the colliding pair); nothing raises
  out of a callback, so the node keeps serving. The attack itself queries no planner; the
  task's witness (``solvable`` requests, and every request with ``search_witness``) is found
  first by one RRTConnect run in a planning worker, cached per task (``attack.edges``), and its
  time is logged, not counted in ``compute_time_s``.
  A repeat of a request already answered under the same settings (the attack parameters and
  task options) gets that answer again at once, without recomputing it: an attack is
  deterministic for its request, and clients resend a request that has no answer yet
  (``ServiceClient.call_client``), so a long first attack would otherwise queue identical
  ones behind it. The last ``ANSWER_MEMO`` answers with boxes (success, partial) are kept; an
  error is answered again (a bad request at once; a failed witness search is searched again,
  ``planning.witness``).
- ``~/get_info`` (advocc_msgs/srv/GetInfo): robot, grid, heatmap summary, parameters as JSON.

Topics: ``~/heatmap`` (sensor_msgs/PointCloud2, latched, published once at start-up): x, y, z,
intensity = H of the voxels at or above the ``heatmap_percentile`` of the non-zero voxels (80:
the top 20 %), in ``base_frame``, for RViz (``config/advocc.rviz``). A request's ``cloud`` (the
sensed part of the scene) becomes one more scene object, an octree of ``cloud_resolution``.
"""

from __future__ import annotations

import array
import dataclasses
import json
import math
import sys

from advocc_msgs.msg import ErrorCodes
from advocc_msgs.srv import Attack, GetInfo
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from advocc_ros.attack import AttackConfig, AttackStatus, available_methods
from advocc_ros.attack.edges import attack_task
from advocc_ros.attack.task import TaskOptions, task_options
from advocc_ros.attack.types import DEFAULT_METHOD, POLICIES
from advocc_ros.ros.conversions import (goal_region_from_msg, obstacle_to_msg, q_from_joint_state,
                                        scene_from_msgs)
from advocc_ros.heatmap import HeatmapError, hottest_voxels, link_tables, load_heatmap
from advocc_ros.heatmap.store import check_robot, locked_joints
from advocc_ros.nodes import run
from advocc_ros.paths import allowed_dirs, confine
from advocc_ros.model.cache import BoundedCache
from advocc_ros.model.robot import RobotError, RobotSpec, load_robot, resolve_path
from advocc_ros.model.cloud import DEFAULT_RESOLUTION_M
from advocc_ros.model.pose import SceneError
from advocc_ros.model.scene import SceneObject
from advocc_ros.ros.clouds import cloud_msg, cloud_shape_from_msg
from advocc_ros.ros.digest import message_digest
from advocc_ros.ros.params import INT_MAX, Param, declare
from advocc_ros.ros.qos import LATCHED_QOS

# AttackConfig fields exposed as parameters (same names, same defaults).
_CONFIG_PARAMS = tuple(f.name for f in dataclasses.fields(AttackConfig))
_ROBOT_PARAMS = {'robot_urdf': 'urdf', 'robot_srdf': 'srdf', 'robot_group': 'group',
                 'robot_ee_link': 'ee_link'}
_INF = float('inf')
_CONFIG_DOC = {  # description, then (low, high) or constraints AttackConfig checks itself
    'box_size_m': ("s: box edge when a request's box_size is 0 [m]", 'in (0, max_box_m]'),
    'corridor_radius_m': ('r_corr: candidate centres within this distance of the start-goal '
                          'segment [m]', '> 0'),
    'd_safe_m': ('clearance of every box from the robot at start and from the goal region [m]',
                 (0.0, _INF)),
    'd_min_m': ('minimum distance between box centres [m]', (0.0, _INF)),
    'victim_margin_m': ('distance every box keeps from the witness and a joint goal beyond the '
                        'certificate\'s guard margin (room for victims\' collision models), '
                        'and the scene clearance the kept witness is chosen for [m]',
                        (0.0, 0.05)),
    'max_budget': ('larger budgets are rejected', (1, INT_MAX)),
    'max_box_m': ('larger boxes are rejected [m]', '> 0'),
    'protect_goal_hand': ('also keep d_safe from the hand at one goal IK solution (not in the '
                          'paper)', ''),
    'goal_policy': ('goal policy of requests that name none', f'one of {list(POLICIES)}'),
    'reachable_fraction': ('under the reachable policy: share of the fixed goal samples that '
                           'must stay valid', (0.0, 1.0)),
    'max_rejections': ('picks failing the exact check before a method gives up',
                       (0, INT_MAX)),
    'search_witness': ('paper/reachable requests: also find the task\'s witness (one '
                       'RRTConnect run on the unattacked scene, cached) so the verdict can be '
                       'certified; off: no planner is started', ''),
}


TASK_PREFIX = 'task_'
"""Parameter ``task_<option>`` is ``TaskOptions.<option>`` of the ``task`` requests."""
_TASK_DOC = {
    'approach_goals': 'goal configurations the approaches run to',
    'approach_points': 'configurations on the final half of each approach path',
    'detours': 'approach paths per goal through a perturbed midpoint',
    'detour_rad': 'standard deviation of the midpoint perturbation per joint [rad]',
    'tube_samples': 'solvable: configurations drawn around the witness path',
    'tube_rad': 'solvable: perturbation of the witness states per joint [rad]',
    'pocket_samples': 'joint goals: configurations drawn around the goal (its pocket)',
    'pocket_rad': 'joint goals: perturbation of the goal in its pocket per joint [rad]',
    'pocket_tier': 'joint goals, 1: the goal\'s pocket is the first tier (0: with the approaches)',
    'tube_tier': 'solvable, 1: the tube is in the goal tier (0: with the approaches)',
    'cut_routes': 'solvable, 1: the other candidate witnesses are rays for the boxes to cut',
    'corridor_routes': 'solvable: paths beside the witness for the boxes to cut (0: none)',
    'corridor_rad': 'solvable: offset of the corridor routes per joint [rad]',
    'exit_rays': 'joint goals, solvable: keep the witness whose boxes leave fewest of this many '
                 'RRT steps from the goal free (0: off)',
    'exit_rounds': 'with exit_rays: fresh draws of rays, each counting the latest placement; '
                   'after one that finds exits the boxes are placed again to close them',
}


def task_parameters(options: dict) -> dict:
    """The server parameters (``task_<option>``: value) that give a ``task`` attack the
    options of ``options`` (checked by ``task_options``: ``ValueError`` naming a bad one)."""
    checked = task_options(options)
    return {f'{TASK_PREFIX}{name}': getattr(checked, name) for name in options}


def _config_param(name: str) -> Param:
    description, limits = _CONFIG_DOC.get(name, (f'AttackConfig.{name}', ''))
    default = getattr(AttackConfig, name)
    if isinstance(limits, tuple):
        return Param(name, default, description, low=limits[0], high=limits[1])
    return Param(name, default, description, constraints=limits)


PARAMETERS = (
    Param('heatmap_file', '', 'heatmap .npz (required; `advocc heatmap build`)',
          read_only=True),
    *(_config_param(name) for name in _CONFIG_PARAMS),
    *(Param(f'{TASK_PREFIX}{f.name}', f.default, f'task method: {_TASK_DOC[f.name]} '
            f'(TaskOptions.{f.name})') for f in dataclasses.fields(TaskOptions)),
    *(Param(param, getattr(RobotSpec(), field), f'robot description: RobotSpec.{field}',
            read_only=True) for param, field in _ROBOT_PARAMS.items()),
    Param('robot_locked', [''], "joint=value of the joints outside the group (['']: the "
          "heatmap file's values)", read_only=True),
    Param('base_frame', RobotSpec.base_frame, "frame of every request's poses (no tf here)",
          read_only=True),
    Param('allowed_dirs', [''], "directories the node may read files from (['']: the "
          'defaults, see README "Security")', read_only=True),
    Param('heatmap_percentile', 80.0, '~/heatmap publishes the voxels with H at or above this '
          'percentile of the non-zero H', read_only=True, low=0.0, high=100.0))
"""The server's parameters, with their descriptors."""

STATUS_CODES = {
    AttackStatus.SUCCESS: ErrorCodes.SUCCESS,
    AttackStatus.PARTIAL: ErrorCodes.PARTIAL,
    AttackStatus.INVALID_REQUEST: ErrorCodes.INVALID_REQUEST,
    AttackStatus.UNKNOWN_METHOD: ErrorCodes.UNKNOWN_METHOD,
    AttackStatus.INVALID_START: ErrorCodes.INVALID_ROBOT_STATE,
    AttackStatus.START_IN_COLLISION: ErrorCodes.START_STATE_IN_COLLISION,
    AttackStatus.INVALID_GOAL: ErrorCodes.INVALID_GOAL_CONSTRAINTS,
    AttackStatus.INVALID_LINK: ErrorCodes.INVALID_LINK_NAME,
    AttackStatus.ROBOT_MISMATCH: ErrorCodes.INVALID_ROBOT_STATE,
    AttackStatus.INTERNAL_ERROR: ErrorCodes.INTERNAL_ERROR,
    AttackStatus.NO_WITNESS: ErrorCodes.PLANNING_FAILED,  # the tool's witness search found none
}


ANSWER_MEMO = 16
"""Attack answers the server keeps for repeated requests (module docstring)."""


def non_finite_field(msg, path: str = '') -> str | None:
    """Path of the first NaN/inf number anywhere in a message (nested, arrays), or None."""
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        where = f'{path}.{name}' if path else name
        if isinstance(value, float):
            if not math.isfinite(value):
                return where
        elif hasattr(value, 'get_fields_and_field_types'):
            found = non_finite_field(value, where)
            if found:
                return found
        elif isinstance(value, (bytes, bytearray)) or (
                isinstance(value, array.array) and value.typecode not in 'fd'):
            continue  # raw bytes (a PointCloud2's data), integers: nothing to check
        elif isinstance(value, (list, tuple, array.array)) or hasattr(value, 'dtype'):
            for i, item in enumerate(value):
                if hasattr(item, 'get_fields_and_field_types'):
                    found = non_finite_field(item, f'{where}[{i}]')
                    if found:
                        return found
                elif isinstance(item, float) or hasattr(item, 'dtype'):
                    if not math.isfinite(float(item)):
                        return f'{where}[{i}]'
    return None


def parse_locked(entries) -> tuple[tuple[str, float], ...] | None:
    """The ``robot_locked`` parameter's ``['joint=value', ...]`` as RobotSpec.locked; None
    when no entry is given; ``RobotError`` for an entry that is not a name and a number."""
    entries = [e for e in entries if e]
    if not entries:
        return None
    pairs = []
    for entry in entries:
        name, sep, value = entry.partition('=')
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name.strip() or not math.isfinite(number):
            raise RobotError(f'robot_locked: expected joint=value entries, got {entry!r}')
        pairs.append((name.strip(), number))
    return tuple(sorted(pairs))


class HeatmapServer(Node):
    """Attack service over one heatmap (see the module docstring)."""

    def __init__(self):
        super().__init__('heatmap_server')
        declare(self, PARAMETERS)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.task_options = task_options({  # a bad override stops the node before any work
            name: self.get_parameter(f'{TASK_PREFIX}{name}').value
            for name in (f.name for f in dataclasses.fields(TaskOptions))})
        self._last_stats: dict | None = None
        """The stats of the last attack (``~/get_info``): the Attack response carries none."""
        self._answers: BoundedCache = BoundedCache('attack answers', ANSWER_MEMO)
        """request and settings digest -> (attack number, response, stats): answers with boxes
        (module docstring)."""

        path = self.get_parameter('heatmap_file').value
        if not path:
            raise HeatmapError('parameter heatmap_file is empty: give a heatmap .npz file '
                               '(--ros-args -p heatmap_file:=FILE)')
        self._allowed = allowed_dirs(self.get_parameter('allowed_dirs').value)
        confine(path, self._allowed, 'heatmap_file')
        for param in ('robot_urdf', 'robot_srdf'):
            confine(resolve_path(self.get_parameter(param).value),
                    self._allowed + [resolve_path('example-robot-data://')], param)
        spec = RobotSpec(**{field: self.get_parameter(param).value
                            for param, field in _ROBOT_PARAMS.items()})
        self.heatmap = load_heatmap(path)
        locked = parse_locked(self.get_parameter('robot_locked').value)
        if locked is None:
            locked = locked_joints(self.heatmap.meta, spec.urdf, spec.srdf, spec.group) or ()
        self._spec = dataclasses.replace(spec, locked=locked)
        self.robot = load_robot(self._spec)
        check_robot(self.heatmap, self.robot.hash, path)
        self.cfg = self._config()
        link_tables(self.robot, self.heatmap.lut_pitch_m)  # warm the cache: ~1 s once
        self._path = path
        self._served = 0
        summary = self.heatmap.summary()
        self.get_logger().info(
            f'heatmap {path}: grid {summary["shape"]} x {summary["voxel_m"]} m, '
            f'{summary["valid_samples"]} samples, robot-only={self.heatmap.robot_only}')
        self._heatmap_pub = self.create_publisher(PointCloud2, '~/heatmap', LATCHED_QOS)
        self._publish_heatmap()
        self.create_service(Attack, '~/attack', self._on_attack)
        self.create_service(GetInfo, '~/get_info', self._on_get_info)

    def _publish_heatmap(self) -> None:
        percentile = float(self.get_parameter('heatmap_percentile').value)
        points, H = hottest_voxels(self.heatmap, percentile)
        msg = cloud_msg(points, self.get_parameter('base_frame').value, H)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._heatmap_pub.publish(msg)
        self.get_logger().info(f'published {len(points)} heatmap voxels (H >= the '
                               f'{percentile:g}th percentile) on {self._heatmap_pub.topic_name}')

    # -- parameters --------------------------------------------------------------------------

    def _config(self) -> AttackConfig:
        return AttackConfig(**{name: self.get_parameter(name).value for name in _CONFIG_PARAMS})

    def _check_parameters(self, params) -> SetParametersResult:
        """The attack settings together, as ``AttackConfig`` and ``task_options`` check them
        (ranges, types and read-only are the descriptors', checked by rclpy before this)."""
        values = dataclasses.asdict(self.cfg)
        task = dataclasses.asdict(self.task_options)
        for p in params:
            if p.name in values:
                values[p.name] = p.value
            elif p.name.startswith(TASK_PREFIX) and p.name[len(TASK_PREFIX):] in task:
                task[p.name[len(TASK_PREFIX):]] = p.value
        try:
            cfg = AttackConfig(**values)
            options = task_options(task)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.cfg, self.task_options = cfg, options
        return SetParametersResult(successful=True)

    # -- services ----------------------------------------------------------------------------

    def _on_attack(self, request: Attack.Request, response: Attack.Response
                   ) -> Attack.Response:
        self._served += 1
        try:
            key = self._answer_key(request)
            known = self._answers.get(key)
            if known is not None:
                first, answer, self._last_stats = known
                self.get_logger().info(f'attack #{self._served}: the request and settings of '
                                       f'attack #{first}; its answer again, not recomputed')
                return answer
            response = self._attack(request, response)
            line = f'attack #{self._served}: {response.error_code.val} {response.message}'
            if response.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL):
                self.get_logger().info(line)
                self._answers.put(key, (self._served, response, self._last_stats))
            else:
                self.get_logger().warning(line)
        except Exception as exc:  # never let a callback take the executor down
            response.error_code.val = ErrorCodes.FAILURE
            response.message = f'internal error: {exc}'
            response.obstacles = []
            self.get_logger().error(f'attack #{self._served} failed: {exc!r}')
        return response

    def _answer_key(self, request: Attack.Request) -> str:
        """Digest of the request and of the settings its answer depends on."""
        settings = json.dumps([dataclasses.asdict(self.cfg),
                               dataclasses.asdict(self.task_options)], sort_keys=True)
        return f'{message_digest(request)}:{settings}'

    def _attack(self, request: Attack.Request, response: Attack.Response) -> Attack.Response:
        """Answer one request: its task checked and turned into core types, then the attack
        (budget, box size, method and policy are checked by the core: errors are data)."""
        try:
            objects, q_init, goal = self._task(request)
        except _Refused as exc:
            response.error_code.val = exc.code
            response.message = str(exc)
            return response
        method = request.method or DEFAULT_METHOD
        result = attack_task(self.heatmap, self.robot, objects, q_init, goal,
                             int(request.budget), method, self.cfg,
                             box_size_m=request.box_size or None, seed=request.seed,
                             goal_policy=request.goal_policy or None,
                             method_options=self.task_options if method == 'task' else None)
        self._last_stats = json.loads(json.dumps(result.stats, default=str))
        if 'witness_search_ms' in result.stats:
            self.get_logger().info(f'witness search: {result.stats["witness_search_ms"]:.0f} '
                                   'ms (RRTConnect on the unattacked scene, cached per task)')
        _fill_response(response, result)
        return response

    def _task(self, request: Attack.Request) -> tuple:
        """The request's scene objects, start configuration and goal region; raises
        ``_Refused`` (the code and message of the first thing wrong) for a bad request."""
        bad = non_finite_field(request)
        if bad:
            raise _Refused(ErrorCodes.INVALID_REQUEST, f'{bad}: non-finite number (NaN or inf)')
        self._check_frames(request)
        objects = _scene_objects(request)
        try:
            q_init = q_from_joint_state(self.robot, request.start_state)
        except RobotError as exc:
            raise _Refused(ErrorCodes.INVALID_ROBOT_STATE, str(exc)) from None
        return objects, q_init, self._goal(request.goal_region)

    def _check_frames(self, request: Attack.Request) -> None:
        """Refuse a scene object, goal region or cloud given in a frame other than the robot's
        base frame (the node has no tf)."""
        base = self.get_parameter('base_frame').value
        frames = {(o.header.frame_id, f'scene[{i}] {o.id!r}')
                  for i, o in enumerate(request.scene)}
        frames.add((request.goal_region.header.frame_id, 'goal_region'))
        if request.cloud.width * request.cloud.height:
            frames.add((request.cloud.header.frame_id, 'cloud'))
        for frame, what in sorted(frames):
            if frame and frame != base:
                raise _Refused(ErrorCodes.INVALID_REQUEST if what != 'goal_region'
                               else ErrorCodes.INVALID_GOAL_CONSTRAINTS,
                               f'{what}: frame {frame!r} is not the robot base frame {base!r} '
                               '(no tf here)')

    def _goal(self, gmsg):
        """The goal region of ``gmsg``, refused when a tolerance is negative or it is invalid."""
        if any(v < 0 for v in [*gmsg.position_tolerance, *gmsg.orientation_tolerance]):
            raise _Refused(ErrorCodes.INVALID_GOAL_CONSTRAINTS,
                           'goal_region is inverted: tolerances must be >= 0, got position '
                           f'{list(gmsg.position_tolerance)}, orientation '
                           f'{list(gmsg.orientation_tolerance)}')
        try:
            return goal_region_from_msg(gmsg, self._spec.ee_link)
        except SceneError as exc:
            raise _Refused(ErrorCodes.INVALID_GOAL_CONSTRAINTS, str(exc)) from None

    def info(self) -> dict:
        return {
            'node': self.get_fully_qualified_name(),
            'heatmap_file': self._path,
            'heatmap': self.heatmap.summary(),
            'robot': {'hash': self.robot.hash, 'urdf': self._spec.urdf,
                      'joints': list(self.robot.joint_names), 'ee_link': self._spec.ee_link,
                      'locked': dict(self._spec.locked),
                      'base_frame': self.get_parameter('base_frame').value},
            'grid': self.heatmap.grid.to_data(),
            'robot_only': self.heatmap.robot_only,
            'parameters': dataclasses.asdict(self.cfg),
            'task_options': dataclasses.asdict(self.task_options),
            'last_attack_stats': self._last_stats,
            'methods': available_methods(),
            'requests_served': self._served,
        }

    def _on_get_info(self, request: GetInfo.Request, response: GetInfo.Response
                     ) -> GetInfo.Response:
        try:
            response.info_json = json.dumps(self.info())
            response.success, response.message = True, 'ok'
        except Exception as exc:
            self.get_logger().error(f'get_info failed: {exc!r}')
            response.success, response.message = False, f'internal error: {exc}'
        return response


class _Refused(Exception):
    """A bad attack request: the error code and the message it is answered with."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


def _scene_objects(request: Attack.Request) -> tuple:
    """The request's scene objects, its sensed ``cloud`` (if any) one more, an octree of
    ``cloud_resolution``; a bad object is refused."""
    try:
        objects = scene_from_msgs(list(request.scene))
        if request.cloud.width * request.cloud.height:
            cloud = cloud_shape_from_msg(request.cloud, request.cloud_resolution
                                         or DEFAULT_RESOLUTION_M, [-math.inf] * 3,
                                         [math.inf] * 3)
            if cloud is not None:
                objects = objects + (SceneObject('sensed_cloud', (cloud,)),)
    except SceneError as exc:
        raise _Refused(ErrorCodes.INVALID_REQUEST, str(exc)) from None
    return objects


def _fill_response(response: Attack.Response, result) -> None:
    """``response`` from the attack's ``result``: code, message, boxes, mass, time, verdict."""
    response.error_code.val = STATUS_CODES.get(result.status, ErrorCodes.FAILURE)
    response.message = result.message
    response.obstacles = [obstacle_to_msg(o, m)
                          for o, m in zip(result.obstacles, result.masses)]
    response.total_mass = float(result.total_mass)
    response.compute_time_s = float(result.compute_s)
    response.goal_valid_fraction = (-1.0 if result.goal_valid_fraction is None
                                    else float(result.goal_valid_fraction))
    if result.solvable is not None:
        response.solvable = result.solvable.verdict
        response.solvable_message = result.solvable.message


def main(args=None) -> int:
    return run(HeatmapServer, 'heatmap_server', args,
               startup_errors=(HeatmapError, RobotError, ValueError))


if __name__ == '__main__':
    sys.exit(main())
