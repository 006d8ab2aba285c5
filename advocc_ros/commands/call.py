"""``advocc call attack|info``: call a running heatmap_server (there is no ``ros2`` CLI here)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_scene_args, scene_from_args
from advocc_ros.scene import SceneError


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('call', help='call a running node\'s service')
    csub = parser.add_subparsers(dest='call_command', required=True)

    p = csub.add_parser('attack', help='heatmap_server ~/attack for a scene\'s task')
    add_scene_args(p)
    p.add_argument('--budget', type=int, required=True, help='M, number of boxes')
    p.add_argument('--method', default='ours', help='ours | random | pfa | pfa++')
    p.add_argument('--size', type=float, default=0.0, help='box edge [m]; 0: server default')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--server', default='/heatmap_server', help='node name (default %(default)s)')
    p.add_argument('--timeout', type=float, default=10.0,
                   help='seconds to wait for the service and for the answer each')
    p.add_argument('--out', help='write the obstacles YAML (as `advocc attack --out`)')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_attack)

    p = csub.add_parser('info', help='heatmap_server ~/get_info')
    p.add_argument('--server', default='/heatmap_server')
    p.add_argument('--timeout', type=float, default=10.0)
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_info)


class ServiceClient:
    """One rclpy context, node and executor for calling services from a plain program."""

    def __init__(self, name: str = 'advocc_call'):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f'{name}_{os.getpid()}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict = {}

    def client(self, srv_type, service: str, timeout_s: float):
        """A ready client for ``service``, or ``UserError`` after ``timeout_s``."""
        if service not in self._clients:
            self._clients[service] = self.node.create_client(srv_type, service)
        client = self._clients[service]
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise UserError(f'service {service} is not available after {timeout_s:g} s '
                                '(is the node running, on this ROS_DOMAIN_ID?)')
            self.executor.spin_once(timeout_sec=0.05)
        return client

    def call(self, srv_type, service: str, request, timeout_s: float):
        client = self.client(srv_type, service, timeout_s)
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        if not future.done():
            client.remove_pending_request(future)
            raise UserError(f'{service}: no answer within {timeout_s:g} s')
        if future.exception() is not None:
            raise UserError(f'{service}: call failed ({future.exception()})')
        return future.result()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'ServiceClient':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def attack_request(scene, budget: int, method: str = 'ours', box_size_m: float = 0.0,
                   seed: int = 0):
    """Attack.Request for a scene's objects, start and goal."""
    from advocc_msgs.srv import Attack
    from sensor_msgs.msg import JointState

    from advocc_ros.conversions import collision_object_to_msg, goal_region_to_msg

    if scene.start is None or scene.goal is None:
        raise UserError(f'scene {scene.name!r} needs a start and a goal to attack')
    req = Attack.Request()
    req.scene = [collision_object_to_msg(o, scene.frame) for o in scene.objects]
    req.start_state = JointState(name=list(scene.start),
                                 position=[float(v) for v in scene.start.values()])
    req.goal_region = goal_region_to_msg(scene.goal, scene.frame)
    req.budget, req.method, req.box_size, req.seed = int(budget), method, float(box_size_m), \
        int(seed)
    return req


def _code_name(val: int) -> str:
    from advocc_msgs.msg import ErrorCodes
    names = {getattr(ErrorCodes, n): n for n in dir(ErrorCodes)
             if n.isupper() and isinstance(getattr(ErrorCodes, n), int)}
    return names.get(val, str(val))


def response_data(res, round_trip_s: float | None = None) -> dict:
    """JSON-able answer of an Attack response; ``objects`` in the scene-file format."""
    from advocc_ros.scene import make_box, objects_to_data

    boxes = [make_box(o.id, (o.pose.position.x, o.pose.position.y, o.pose.position.z),
                      tuple(o.size)) for o in res.obstacles]
    data = {'error_code': res.error_code.val, 'status': _code_name(res.error_code.val),
            'message': res.message, 'obstacles': objects_to_data(boxes),
            'masses': [float(o.covered_mass) for o in res.obstacles],
            'total_mass': float(res.total_mass), 'compute_ms': round(res.compute_time_s * 1e3, 3)}
    if round_trip_s is not None:
        data['round_trip_ms'] = round(round_trip_s * 1e3, 3)
    return data


def _attack(args: argparse.Namespace) -> int:
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack

    try:
        scene = scene_from_args(args)
    except SceneError as exc:
        raise UserError(str(exc)) from None
    req = attack_request(scene, args.budget, args.method, args.size, args.seed)
    with ServiceClient() as client:
        client.client(Attack, f'{args.server}/attack', args.timeout)
        t0 = time.perf_counter()
        res = client.call(Attack, f'{args.server}/attack', req, args.timeout)
        data = response_data(res, time.perf_counter() - t0)
    ok = res.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL)
    if args.out and ok:
        from advocc_ros.scene import save_yaml_atomic
        save_yaml_atomic(args.out, {
            'format': 'advocc_obstacles', 'version': 1, 'status': data['status'].lower(),
            'message': data['message'], 'method': args.method, 'budget': args.budget,
            'box_size_m': float(res.obstacles[0].size[0]) if res.obstacles else args.size,
            'masses': data['masses'], 'total_mass': data['total_mass'],
            'compute_ms': data['compute_ms'], 'scene': {'name': scene.name,
                                                       'objects_hash': scene.objects_hash()},
            'server': args.server, 'seed': args.seed, 'objects': data['obstacles']})
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print(f'{data["status"]} ({data["error_code"]}): {data["message"]} '
              f'[compute {data["compute_ms"]:.1f} ms, round trip {data["round_trip_ms"]:.1f} ms]')
        for obj, mass in zip(data['obstacles'], data['masses']):
            x, y, z = obj['pose']['position']
            print(f'  {obj["id"]:8s} centre [{x:+.3f}, {y:+.3f}, {z:+.3f}] m  mass {mass:.3f}')
    if not ok:
        print(f'advocc call attack: {data["status"]}: {data["message"]}', file=sys.stderr)
        return 1
    return 0


def _info(args: argparse.Namespace) -> int:
    from advocc_msgs.srv import GetInfo

    with ServiceClient() as client:
        res = client.call(GetInfo, f'{args.server}/get_info', GetInfo.Request(), args.timeout)
    if not res.success:
        raise UserError(f'{args.server}/get_info: {res.message}')
    info = json.loads(res.info_json)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for key, value in info.items():
            print(f'{key}: {json.dumps(value) if isinstance(value, (dict, list)) else value}')
    return 0
