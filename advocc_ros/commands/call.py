"""``advocc call attack|info``: call a running heatmap_server (there is no ``ros2`` CLI here)."""

from __future__ import annotations

import argparse
import json
import sys
import time

from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_attack_args, add_scene_args, scene_from_args
from advocc_ros.attack.methods import SERVER_METHODS
from advocc_ros.model.pose import SceneError

TIMEOUT_S = 10.0
"""Default wait for the service and for the answer, each [s]."""
SOLVABLE_TIMEOUT_S = 180.0
"""Default wait for a ``--policy solvable`` answer [s]: a task's first such attack finds its
witnesses and samples the judging goal sets before the attack: 35 s on table_pick through this
command, more where goal IK is slow (table_under_pick's judging goal set alone takes 40 s,
docs/performance.md). Repeats are answered at once from the server's memo."""
RESEND_S = 2.0
"""An unanswered attack or info request is sent again after this long, then 2x, 4x ... [s]
(this CLI is a new client on every call: see ``ServiceClient.call_client``)."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('call', help='call a running node\'s service')
    csub = parser.add_subparsers(dest='call_command', required=True)

    p = csub.add_parser('attack', help='heatmap_server ~/attack for a scene\'s task')
    add_scene_args(p)
    p.add_argument('--budget', type=int, required=True, help='M, number of boxes')
    add_attack_args(p, methods=SERVER_METHODS)
    p.add_argument('--server', default='/heatmap_server', help='node name (default %(default)s)')
    p.add_argument('--timeout', type=float, default=None,
                   help='seconds to wait for the service and for the answer each (default '
                        f'{TIMEOUT_S:g}; {SOLVABLE_TIMEOUT_S:g} with --policy solvable)')
    p.add_argument('--out', help='write the obstacles YAML (as `advocc attack --out`)')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_attack)

    p = csub.add_parser('info', help='heatmap_server ~/get_info')
    p.add_argument('--server', default='/heatmap_server')
    p.add_argument('--timeout', type=float, default=TIMEOUT_S)
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_info)


def attack_timeout_s(timeout_s: float | None, policy: str) -> float:
    """The wait of ``advocc call attack``: the one given, else the policy's default."""
    if timeout_s is not None:
        return timeout_s
    return SOLVABLE_TIMEOUT_S if policy == 'solvable' else TIMEOUT_S


def _attack(args: argparse.Namespace) -> int:
    from advocc_msgs.srv import Attack

    from advocc_ros.ros.client import ServiceClient
    from advocc_ros.ros.conversions import attack_request, attack_response_data
    from advocc_ros.ros.errors import ATTACK_OK

    try:
        scene = scene_from_args(args)
        req = attack_request(scene, args.budget, args.method, args.size, args.seed, args.policy)
    except SceneError as exc:
        raise UserError(str(exc)) from None
    timeout_s = attack_timeout_s(args.timeout, args.policy)
    with ServiceClient() as client:
        client.client(Attack, f'{args.server}/attack', timeout_s)
        t0 = time.perf_counter()
        res = client.call(Attack, f'{args.server}/attack', req, timeout_s, RESEND_S)
        data = attack_response_data(res, time.perf_counter() - t0)
    ok = res.error_code.val in ATTACK_OK
    if args.out and ok:
        from advocc_ros.attack.obstacles import obstacles_file_data, save_obstacles
        from advocc_ros.ros.conversions import obstacles_from_msgs
        save_obstacles(args.out, obstacles_file_data(
            obstacles_from_msgs(res.obstacles), args.method, args.budget,
            data['status'].lower(), data['message'],
            box_size_m=None if res.obstacles else args.size, masses=data['masses'],
            total_mass=data['total_mass'], compute_ms=data['compute_ms'],
            scene={'name': scene.name, 'objects_hash': scene.objects_hash()},
            extra={'server': args.server, 'seed': args.seed}))
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

    from advocc_ros.ros.client import ServiceClient

    with ServiceClient() as client:
        res = client.call(GetInfo, f'{args.server}/get_info', GetInfo.Request(), args.timeout,
                          RESEND_S)
    if not res.success:
        raise UserError(f'{args.server}/get_info: {res.message}')
    info = json.loads(res.info_json)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for key, value in info.items():
            print(f'{key}: {json.dumps(value) if isinstance(value, (dict, list)) else value}')
    return 0
