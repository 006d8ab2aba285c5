"""``advocc perf attack``: online attack compute time and heatmap_server round trip.

Wired into ``advocc perf`` by ``commands/perf.py`` calling :func:`register_attack`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import tempfile
import time

import numpy as np

from advocc_ros.attack.types import DEFAULT_METHOD, POLICIES
from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_scene_args, add_task_option_arg
from advocc_ros.ros.spawn import start_node, stop

PAPER_ONLINE_S = 1.27  # paper §V: online attack generation time


def register_attack(sub: argparse._SubParsersAction) -> None:
    """Add ``attack`` to the ``advocc perf`` subcommands."""
    p = sub.add_parser('attack', help='time the online attack (core and service round trip)')
    add_scene_args(p, required=False)
    p.set_defaults(scene='table_pick')
    p.add_argument('--heatmap', help='heatmap file (default: build one with --samples)')
    p.add_argument('--samples', type=int, default=3000,
                   help='samples of the heatmap built when --heatmap is not given')
    p.add_argument('--budgets', default='1,3,5', help='comma-separated budgets')
    p.add_argument('--method', default=DEFAULT_METHOD, help='attack method (default %(default)s)')
    p.add_argument('--policy', default='paper', choices=POLICIES,
                   help='goal policy (default %(default)s)')
    add_task_option_arg(p)
    p.add_argument('--repeats', type=int, default=5,
                   help='cold and warm runs per budget (each a new task)')
    p.add_argument('--calls', type=int, default=30, help='service calls per budget')
    p.add_argument('--no-service', action='store_true', help='skip the round-trip benchmark')
    p.add_argument('--domain', type=int, help='ROS_DOMAIN_ID for the server (default: private)')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_perf_attack)


def _stats_ms(values_s: list[float]) -> dict:
    ms = np.asarray(values_s) * 1e3
    return {'median_ms': round(float(np.median(ms)), 3),
            'p95_ms': round(float(np.percentile(ms, 95)), 3),
            'min_ms': round(float(ms.min()), 3), 'n': int(ms.size)}


def _core(heatmap, robot, scene, q, budgets, method, repeats, policy='paper',
          options=None) -> dict:
    """Times per budget, each repeat a new task to the tool (``options``: the method's
    ``method_options``): ``cold``, the edges and the core with every cache empty (the witness
    search on an empty disk cache, the task's goal sample, the attack); ``warm``, the same call
    again (witness and samples cached); ``compute``, the core's own ``compute_s`` of the warm
    call."""
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.model.cache import clear_task_caches, disk_cache_at
    from advocc_ros.planning.witness_cache import WITNESSES

    def run(budget: int, seed: int):
        t0 = time.perf_counter()
        res = attack_task(heatmap, robot, scene.objects, q, scene.goal, budget, method,
                          seed=seed, goal_policy=policy, method_options=options)
        if not res.status.ok:
            raise UserError(f'attack failed: {res.status.value}: {res.message}')
        return res, time.perf_counter() - t0

    run(budgets[0], 0)  # models, JIT
    out = {}
    for budget in budgets:
        cold, warm, compute = [], [], []
        for rep in range(max(repeats, 1)):
            with tempfile.TemporaryDirectory(prefix='advocc_perf_cache_') as empty, \
                    disk_cache_at(empty):
                clear_task_caches()
                WITNESSES.clear()
                cold.append(run(budget, rep)[1])
                res, wall = run(budget, rep)
            warm.append(wall)
            compute.append(res.compute_s)
        out[str(budget)] = {'cold': _stats_ms(cold), 'warm': _stats_ms(warm),
                            'compute': _stats_ms(compute), 'boxes': len(res.obstacles),
                            'status': res.status.value}
    return out


def _service(heatmap_path, scene, budgets, method, calls, domain, server_params=None) -> dict:
    """Round trips to a heatmap_server started here (``server_params``: more parameters)."""
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack

    from advocc_ros.ros.client import ServiceClient, ServiceError
    from advocc_ros.ros.conversions import attack_request

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1')
    os.environ['ROS_DOMAIN_ID'] = str(domain)  # this process's client joins the same domain
    log = tempfile.TemporaryFile(mode='w+')
    proc = start_node('heatmap_server', {'heatmap_file': heatmap_path, **(server_params or {})},
                      env=env, log=log)
    try:
        with ServiceClient('advocc_perf') as client:
            t0 = time.perf_counter()
            deadline = time.monotonic() + 60
            service = '/heatmap_server/attack'
            while True:
                if proc.poll() is not None:
                    log.seek(0)
                    raise UserError(f'heatmap_server exited ({proc.returncode}):\n{log.read()}')
                try:
                    client.client(Attack, service, 1.0)
                    break
                except ServiceError:
                    if time.monotonic() > deadline:
                        raise
            startup_s = time.perf_counter() - t0
            out = {'server_startup_s': round(startup_s, 3)}
            for budget in budgets:
                # Seeds 0, 1, ... as the core runs, the warm-up after them: each call its own
                # request, since the server answers a repeat from its memo without computing.
                req = attack_request(scene, budget, method, seed=max(calls, 1))
                client.call(Attack, service, req, 30.0)  # warm-up
                rtt, compute = [], []
                for seed in range(max(calls, 1)):
                    req.seed = seed
                    t0 = time.perf_counter()
                    res = client.call(Attack, service, req, 30.0)
                    rtt.append(time.perf_counter() - t0)
                    compute.append(res.compute_time_s)
                    if res.error_code.val not in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL):
                        raise UserError(f'attack failed: {res.error_code.val} {res.message}')
                out[str(budget)] = {'round_trip': _stats_ms(rtt),
                                    'server_compute': _stats_ms(compute)}
            return out
    finally:
        stop(proc)
        log.close()


def _perf_attack(args: argparse.Namespace) -> int:
    """``advocc perf attack``: time the core, then (unless ``--no-service``) the round trips to
    a heatmap_server serving the same heatmap; print the medians or the report as JSON."""
    from advocc_ros.evaluation.perf import machine
    from advocc_ros.commands.common import task_options_from_args

    options = task_options_from_args(args, args.method)
    budgets, scene, robot, q = _task(args)
    with tempfile.TemporaryDirectory(prefix='advocc_perf_') as tmp:
        heatmap, path = _heatmap(args, scene, robot, pathlib.Path(tmp))
        report = {
            'benchmark': 'online attack', 'scene': scene.name, 'method': args.method,
            'heatmap': str(args.heatmap or f'built: {args.samples} samples'),
            'grid_shape': list(heatmap.grid.shape), 'voxel_m': heatmap.grid.voxel_m,
            'policy': args.policy,
            'task_options': None if options is None else dataclasses.asdict(options),
            'core': _core(heatmap, robot, scene, q, budgets, args.method, args.repeats,
                          args.policy, options),
        }
        if not args.no_service:
            domain = args.domain if args.domain is not None else 150 + os.getpid() % 80
            from advocc_ros.nodes.heatmap_server import task_parameters
            params = dict(task_parameters(report['task_options'] or {}), goal_policy=args.policy)
            report['service'] = _service(path, scene, budgets, args.method, args.calls, domain,
                                         params)
    report['paper_online_s'] = PAPER_ONLINE_S
    report['machine'] = machine()
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_report(report, scene.name, budgets, args.method)
    return 0


def _task(args: argparse.Namespace) -> tuple:
    """The budgets, the scene (which must have a start and a goal), its robot and start
    configuration named by ``args``; a bad one is a ``UserError``."""
    from advocc_ros.commands.common import scene_from_args
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.robot import load_robot

    try:
        budgets = [int(b) for b in args.budgets.split(',') if b.strip()]
        scene = scene_from_args(args)
    except (ValueError, SceneError) as exc:
        raise UserError(str(exc)) from None
    if scene.start is None or scene.goal is None:
        raise UserError(f'{args.scene}: the scene needs a start and a goal')
    robot = load_robot(scene.robot)
    q = robot.q_from_names(list(scene.start), list(scene.start.values()))
    return budgets, scene, robot, q


def _heatmap(args: argparse.Namespace, scene, robot, tmp: pathlib.Path) -> tuple:
    """The heatmap timed and its file: ``--heatmap`` loaded, or one of ``--samples`` built and
    saved in ``tmp`` (for the server to load)."""
    from advocc_ros.heatmap import (HeatmapConfig, HeatmapError, build_heatmap, load_heatmap,
                                    save_heatmap)

    if args.heatmap:
        path = pathlib.Path(args.heatmap)
        try:
            return load_heatmap(path, robot_hash=robot.hash), path
        except HeatmapError as exc:
            raise UserError(str(exc)) from None
    heatmap = build_heatmap(scene, HeatmapConfig(samples=args.samples), seed=0)
    path = tmp / 'heatmap.npz'
    save_heatmap(heatmap, path)
    return heatmap, path


def _print_report(report: dict, scene_name: str, budgets: list[int], method: str) -> None:
    """The report's medians per budget, one line each, and the paper's online time."""
    print(f'online attack, {scene_name}, method {method}, grid '
          f'{report["grid_shape"]} x {report["voxel_m"]} m')
    for budget in budgets:
        row = report['core'][str(budget)]
        line = (f'  M={budget}: cold {row["cold"]["median_ms"]:.0f} ms, warm '
                f'{row["warm"]["median_ms"]:.0f} ms, core {row["compute"]["median_ms"]:.1f} '
                f'ms (medians of {row["compute"]["n"]})')
        if 'service' in report:
            rtt = report['service'][str(budget)]['round_trip']
            line += (f'; service round trip {rtt["median_ms"]:.1f} ms median, '
                     f'{rtt["p95_ms"]:.1f} ms p95')
        print(line)
    print(f'  paper: {PAPER_ONLINE_S * 1e3:.0f} ms')
