"""``advocc perf load``: concurrent clients against heatmap_server ``~/attack`` and planner_shim
``~/plan``; failed requests, latency p50/p99, throughput, and each node's RSS over time.

Each client is its own process (its own rclpy context, no shared GIL) that waits for a common
"go", fires its requests back to back and reports per-request round trips. The nodes run as
child processes on a private ROS domain and namespace; their resident memory is sampled from
``/proc/<pid>/status`` before the load (after one warm-up request), every 0.2 s during it, and
after it, so a leak shows up as growth from the first to the last part of the run.

Wired into ``advocc perf`` by ``commands/perf.py`` calling :func:`register_load`.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from advocc_ros.cli import UserError
from advocc_ros.ros.spawn import start_node, stop


LOAD_METHOD = 'ours'
"""Attack method of every load request: the paper's method, as in the load figures of
docs/performance.md (named here: the CLI's default method is ``task`` now)."""


def register_load(sub: argparse._SubParsersAction) -> None:
    """Add ``load`` to the ``advocc perf`` subcommands."""
    p = sub.add_parser('load', help='concurrent clients on ~/attack and ~/plan (latency, RSS)')
    p.add_argument('--scene', default='table_pick')
    p.add_argument('--heatmap', help='heatmap file (default: build one with --samples)')
    p.add_argument('--samples', type=int, default=3000)
    p.add_argument('--clients', type=int, default=8, help='concurrent ~/attack clients')
    p.add_argument('--requests', type=int, default=500, help='~/attack requests per client')
    p.add_argument('--budget', type=int, default=1, help='M of every attack request')
    p.add_argument('--plan-clients', type=int, default=4, help='concurrent ~/plan clients')
    p.add_argument('--plan-requests', type=int, default=25, help='~/plan requests per client')
    p.add_argument('--plan-budget', type=float, default=1.0, help='plan time budget [s]')
    p.add_argument('--no-plan', action='store_true', help='skip the ~/plan load')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_perf_load)


# --------------------------------------------------------------------------------------------
# Client processes

def _client_main(kind: str, service: str, scene_name: str, n: int, budget: float,
                 seed: int) -> None:
    """One client: ready -> wait for 'go' on stdin -> n requests -> one JSON line of results."""
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack, Plan
    from sensor_msgs.msg import JointState

    from advocc_ros.ros.client import ServiceClient, ServiceError
    from advocc_ros.ros.conversions import attack_request
    from advocc_ros.ros.conversions import goal_region_to_msg
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import load_scene

    scene = load_scene(scene_path(scene_name))
    if kind == 'attack':
        srv, req = Attack, attack_request(scene, int(budget), LOAD_METHOD)
        ok = (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL)
    else:
        srv = Plan
        req = Plan.Request(planner_id='rrtconnect', time_budget_s=float(budget))
        req.start_state = JointState(name=list(scene.start),
                                     position=[float(v) for v in scene.start.values()])
        req.goal_region = goal_region_to_msg(scene.goal, scene.frame)
        ok = (ErrorCodes.SUCCESS,)  # the scene is easy: a timeout under load is a finding
    with ServiceClient(f'load_{kind}_{seed}') as client:
        client.client(srv, service, 120.0)
        print('ready', flush=True)
        sys.stdin.readline()
        latencies, codes, failed, t_start = [], {}, 0, time.time()
        for k in range(n):
            req.seed = seed * 100_000 + k  # distinct requests: the server answers a repeat
            # from its memo without computing it again
            t0 = time.perf_counter()
            try:
                res = client.call(srv, service, req, 60.0 + budget)
                code = res.error_code.val
            except ServiceError:
                code = 'no_answer'
            latencies.append(time.perf_counter() - t0)
            codes[str(code)] = codes.get(str(code), 0) + 1
            failed += code not in ok
        print(json.dumps({'latencies_s': latencies, 'codes': codes, 'failed': failed,
                          't_start': t_start, 't_end': time.time()}), flush=True)


# --------------------------------------------------------------------------------------------
# Measuring

def rss_kb(pid: int) -> int | None:
    """Resident set size of a process [kB] from /proc, or None once it is gone."""
    try:
        with open(f'/proc/{pid}/status') as handle:
            for line in handle:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _children(pid: int) -> list[int]:
    try:
        text = pathlib.Path(f'/proc/{pid}/task/{pid}/children').read_text()
    except OSError:
        return []
    return [int(p) for p in text.split()]


class RssSampler:
    """Samples a process's RSS (and its children's, e.g. the planning worker) in a thread."""

    def __init__(self, pid: int, period_s: float = 0.2):
        self.pid, self.period_s = pid, period_s
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def total_kb(self) -> int:
        return sum(rss_kb(p) or 0 for p in [self.pid, *_children(self.pid)])

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.time(), self.total_kb()))
            self._stop.wait(self.period_s)

    def __enter__(self) -> 'RssSampler':
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _run_load(kind: str, service: str, scene: str, clients: int, n: int, budget: float,
              env: dict, node_pid: int) -> dict:
    """Start ``clients`` client processes, release them together, gather their results."""
    procs = [subprocess.Popen(
        [sys.executable, '-P', '-c', 'import sys; from advocc_ros.commands.perf_load import '
         '_client_main; _client_main(*sys.argv[1:4], int(sys.argv[4]), float(sys.argv[5]), '
         'int(sys.argv[6]))', kind, service, scene, str(n), str(budget), str(i)],
        env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True) for i in range(clients)]
    try:
        for proc in procs:
            line = proc.stdout.readline().strip()
            if line != 'ready':
                raise UserError(f'{kind} client did not start:\n{proc.stderr.read()[-2000:]}')
        sampler = RssSampler(node_pid)
        before_kb = sampler.total_kb()
        with sampler:
            t0 = time.time()
            for proc in procs:
                proc.stdin.write('go\n')
                proc.stdin.flush()
            results = []
            for proc in procs:
                line = proc.stdout.readline()
                if not line:
                    raise UserError(f'{kind} client died:\n{proc.stderr.read()[-2000:]}')
                results.append(json.loads(line))
            wall_s = time.time() - t0
        time.sleep(1.0)
        after_kb = sampler.total_kb()
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)
    lat = np.concatenate([r['latencies_s'] for r in results]) * 1e3
    codes: dict[str, int] = {}
    for r in results:
        for code, count in r['codes'].items():
            codes[code] = codes.get(code, 0) + count
    rss = np.array([kb for _, kb in sampler.samples], dtype=float)
    quarter = max(len(rss) // 4, 1)
    return {
        'clients': clients, 'requests_per_client': n, 'requests': int(lat.size),
        'failed': int(sum(r['failed'] for r in results)), 'codes': codes,
        'latency_ms': {'p50': round(float(np.percentile(lat, 50)), 2),
                       'p99': round(float(np.percentile(lat, 99)), 2),
                       'max': round(float(lat.max()), 2), 'mean': round(float(lat.mean()), 2)},
        'wall_s': round(wall_s, 2), 'throughput_per_s': round(lat.size / wall_s, 1),
        'rss_mb': {'before': round(before_kb / 1024, 1),
                   'during_max': round(float(rss.max()) / 1024, 1) if rss.size else None,
                   'first_quarter_mean': round(float(rss[:quarter].mean()) / 1024, 1),
                   'last_quarter_mean': round(float(rss[-quarter:].mean()) / 1024, 1),
                   'after': round(after_kb / 1024, 1),
                   'samples': int(rss.size)},
    }


def _warm_up(kind: str, service: str, scene: str, budget: float, env: dict) -> None:
    """One request through a client process, so 'before' is measured on a warm node."""
    _run_load(kind, service, scene, 1, 1, budget, env, os.getpid())


def run_load(scene: str = 'table_pick', heatmap: str | None = None, samples: int = 3000,
             clients: int = 8, requests: int = 500, budget: int = 1, plan_clients: int = 4,
             plan_requests: int = 25, plan_budget: float = 1.0, plan: bool = True) -> dict:
    """The whole benchmark; returns the report (also used by the scaled-down test)."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import load_scene

    ns = f'/load{os.getpid()}'
    env = dict(os.environ,
               ROS_DOMAIN_ID=os.environ.get('ROS_DOMAIN_ID', str(150 + os.getpid() % 80)),
               ROS_LOCALHOST_ONLY='1', PYTHONUNBUFFERED='1')
    report: dict = {'benchmark': 'load', 'scene': scene}
    with tempfile.TemporaryDirectory(prefix='advocc_load_') as tmp:
        path = heatmap
        if path is None:
            path = str(pathlib.Path(tmp) / 'heatmap.npz')
            save_heatmap(build_heatmap(load_scene(scene_path(scene)),
                                       HeatmapConfig(samples=samples), seed=0), path)
        report['heatmap'] = heatmap or f'built: {samples} samples'
        logs = {m: open(pathlib.Path(tmp) / f'{m}.log', 'w+')
                for m in ('heatmap_server', 'planner_shim')}
        server = start_node('heatmap_server', {'heatmap_file': path}, {'__ns': ns}, env,
                            logs['heatmap_server'])
        shim = start_node('planner_shim', {'scene_file': scene}, {'__ns': ns}, env,
                          logs['planner_shim']) if plan else None
        try:
            service = f'{ns}/heatmap_server/attack'
            _warm_up('attack', service, scene, budget, env)
            report['attack'] = _run_load('attack', service, scene, clients, requests, budget,
                                         env, server.pid)
            report['attack']['budget'] = budget
            if shim is not None:
                service = f'{ns}/planner_shim/plan'
                _warm_up('plan', service, scene, plan_budget, env)
                report['plan'] = _run_load('plan', service, scene, plan_clients, plan_requests,
                                           plan_budget, env, shim.pid)
                report['plan']['time_budget_s'] = plan_budget
            for name, proc in (('heatmap_server', server), ('planner_shim', shim)):
                if proc is not None and proc.poll() is not None:
                    logs[name].seek(0)
                    raise UserError(f'{name} exited during the load:\n{logs[name].read()}')
        except UserError:
            raise
        finally:
            for proc in (server, shim):
                if proc is not None:
                    stop(proc)
            for log in logs.values():
                log.close()
    return report


def _perf_load(args: argparse.Namespace) -> int:
    from advocc_ros.evaluation.perf import machine
    if min(args.clients, args.requests, args.plan_clients, args.plan_requests) < 1:
        raise UserError('--clients, --requests, --plan-clients and --plan-requests must be >= 1')
    report = run_load(args.scene, args.heatmap, args.samples, args.clients, args.requests,
                      args.budget, args.plan_clients, args.plan_requests, args.plan_budget,
                      not args.no_plan)
    report['machine'] = machine()
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for kind in ('attack', 'plan'):
            if kind not in report:
                continue
            r = report[kind]
            print(f'~/{kind}: {r["clients"]} clients x {r["requests_per_client"]} = '
                  f'{r["requests"]} requests, {r["failed"]} failed, codes {r["codes"]}')
            print(f'  latency p50 {r["latency_ms"]["p50"]} ms, p99 {r["latency_ms"]["p99"]} ms;'
                  f' throughput {r["throughput_per_s"]}/s over {r["wall_s"]} s')
            m = r['rss_mb']
            print(f'  node RSS before {m["before"]} MB, during max {m["during_max"]} MB '
                  f'(first quarter {m["first_quarter_mean"]}, last quarter '
                  f'{m["last_quarter_mean"]}), after {m["after"]} MB')
    failed = sum(report[k]['failed'] for k in ('attack', 'plan') if k in report)
    return 1 if failed else 0
