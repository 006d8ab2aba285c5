"""orchestrator: runs the paper's benchmark through real nodes (SPEC §6, issue 6).

A plain Python program (there is no ``launch`` wheel) that, per scene,

1. starts ``heatmap_server`` (when an attack still has to be generated) and K ``planner_shim``
   processes as children, each in its own process group, on a unique node name, and waits until
   their services answer; with ``external_shims`` it also uses shims of the same ROS domain found
   by their ``*/plan`` services (other hosts), after checking they hold the same scene;
2. for each unit of the run plan (``advocc_ros.bench.protocol.plan_units``): takes the attack from the
   run folder's cache or asks the heatmap server for it (and caches it), injects it into every
   shim on ``/advocc/collision_object`` (REMOVE all injected objects, ADD the boxes under ids
   unique to the attack), waits until each shim's ``~/get_info`` lists exactly those ids (no
   trial ever plans against a stale scene), then spreads the unit's unfinished trials over the
   shims' ``~/plan`` services, one request in flight per shim;
3. computes SMR/CMR/JDS from each returned trajectory and appends the trial's record (JSON line,
   fsync) to ``records.jsonl``; re-running the same command resumes from it.

Children are supervised: a node that dies (``kill -9``) or a shim that stops answering is
restarted (its process group killed first), its in-flight trial goes back to the queue, and it
re-syncs the current obstacles before planning again. Every child is stopped on success, error,
Ctrl-C or SIGTERM (SIGINT to its group, SIGKILL after a grace period), and dies with the
orchestrator even on SIGKILL (``PR_SET_PDEATHSIG``).

Outputs (``write_report``): Tables I, II, IV as Markdown and CSV, the baseline table, PSR-vs-budget
figures and a heatmap slice with the placed obstacles per scene, ``summary.json``.
"""

from __future__ import annotations

import collections
import ctypes
import dataclasses
import json
import logging
import os
import pathlib
import signal
import queue
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

from advocc_ros.bench.protocol import (BASELINE, AttackSpec, BenchConfig, BenchError, RecordStore, Trial,
                              Unit, cell_rows, check_run_config, plan_units, progress_summary,
                              run_lock, table1, table2, table4, baseline_table)
from advocc_ros.fileio import atomic_write_text

log = logging.getLogger(__name__)

# Plan outcomes that say the protocol itself is wrong (not the attack): stop the benchmark.
_FATAL_CODES = {'INVALID_REQUEST', 'UNKNOWN_METHOD', 'INVALID_ROBOT_STATE',
                'INVALID_GOAL_CONSTRAINTS', 'START_STATE_IN_COLLISION'}
_CRASH_RETRIES = 2
_STOP_GRACE_S = 10.0
_SYNC_POLL_S = 0.2
_PR_SET_PDEATHSIG = 1
_LIBC = ctypes.CDLL(None, use_errno=True)


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT): stop children, keep finished trials."""


def _die_with_parent() -> None:  # runs in the child between fork and exec
    _LIBC.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def node_name(text: str) -> str:
    """A valid ROS node name fragment."""
    out = ''.join(c if c.isalnum() or c == '_' else '_' for c in text)
    return out if out[:1].isalpha() else f'n_{out}'


# --------------------------------------------------------------------------------------------
# Child processes

class Child:
    """One node process: own process group, log file, restart with a count."""

    def __init__(self, name: str, module: str, params: dict[str, Any], env: dict,
                 log_dir: pathlib.Path):
        self.name, self.module, self.params, self.env = name, module, params, env
        self.log_path = log_dir / f'{name}.log'
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self.started_at = 0.0

    @property
    def restarts(self) -> int:
        return max(0, self.starts - 1)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc else None

    def start(self) -> None:
        args = [sys.executable, '-m', f'advocc_ros.nodes.{self.module}', '--ros-args',
                '-r', f'__node:={self.name}']
        for key, value in self.params.items():
            if isinstance(value, bool):
                value = 'true' if value else 'false'
            args += ['-p', f'{key}:={value}']
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'ab') as handle:
            handle.write(f'\n=== start #{self.starts + 1} at {time.ctime()}: '
                         f'{" ".join(args)}\n'.encode())
            handle.flush()
            self.proc = subprocess.Popen(args, env=self.env, stdin=subprocess.DEVNULL,
                                         stdout=handle, stderr=subprocess.STDOUT,
                                         start_new_session=True, preexec_fn=_die_with_parent)
        self.starts += 1
        self.started_at = time.monotonic()
        log.info('started %s (pid %d)', self.name, self.proc.pid)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def _signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def stop(self, grace_s: float = _STOP_GRACE_S) -> int | None:
        """SIGINT to the group, SIGKILL after ``grace_s``; the group's leftovers are killed."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self._signal_group(signal.SIGINT)
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                log.warning('%s ignored SIGINT for %.0f s: SIGKILL', self.name, grace_s)
        self._signal_group(signal.SIGKILL)  # e.g. a planning worker left behind
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        return self.proc.returncode

    def restart(self) -> None:
        self.stop(grace_s=2.0)
        self.start()

    def tail(self, lines: int = 20) -> str:
        try:
            return '\n'.join(self.log_path.read_text(errors='replace').splitlines()[-lines:])
        except OSError:
            return ''


# --------------------------------------------------------------------------------------------
# ROS side

class CallFailed(RuntimeError):
    """A service call that got no answer (dead or hung node)."""


class Graph:
    """The orchestrator's rclpy context, node, executor and collision-object publisher."""

    def __init__(self, domain: int | None):
        import rclpy
        from advocc_msgs.msg import CollisionObject
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, LATCHED_QOS

        self._rclpy = rclpy
        self.context = rclpy.Context()
        # Our own SIGINT/SIGTERM handling: rclpy's would shut the context down under us.
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f'advocc_orchestrator_{os.getpid()}',
                                      context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.publisher = self.node.create_publisher(CollisionObject, COLLISION_OBJECT_TOPIC,
                                                    LATCHED_QOS)

    def spin(self, timeout_s: float = 0.02) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def client(self, srv_type, service: str):
        return self.node.create_client(srv_type, service)

    def drop(self, client) -> None:
        if client is not None:
            self.node.destroy_client(client)

    def call(self, client, request, timeout_s: float, alive=lambda: True):
        """Blocking call that keeps spinning; ``CallFailed`` on timeout or a dead server."""
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline or not alive():
                raise CallFailed(f'{client.srv_name} is not available')
            self.spin(0.05)
        future = client.call_async(request)
        while not future.done():
            if time.monotonic() > deadline or not alive():
                client.remove_pending_request(future)
                raise CallFailed(f'{client.srv_name}: no answer within {timeout_s:g} s'
                                 if alive() else f'{client.srv_name}: the node died')
            self.spin(0.05)
        if future.exception() is not None:
            raise CallFailed(f'{client.srv_name}: {future.exception()}')
        return future.result()

    def plan_services(self) -> list[str]:
        """Node names (``/ns/name``) serving an advocc Plan service on this domain."""
        return sorted(name[:-len('/plan')] for name, types in
                      self.node.get_service_names_and_types()
                      if name.endswith('/plan') and 'advocc_msgs/srv/Plan' in types)

    def close(self) -> None:
        try:
            self.executor.shutdown()
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.context)


class _Query:
    """One planner query of a planner-in-the-loop attack, answered by a shim."""

    def __init__(self, q_start, obstacles: tuple, goal, planner_id: str, time_budget_s: float,
                 seed: int):
        self.q_start, self.obstacles, self.goal = np.asarray(q_start, float), obstacles, goal
        self.planner_id, self.time_budget_s, self.seed = planner_id, time_budget_s, seed
        self.key = tuple((tuple(np.round(sh.pose.position_m, 9)), tuple(sh.dims))
                         for o in obstacles for sh in o.shapes)
        self.result = None
        self.event = threading.Event()

    def done(self, res, robot) -> None:
        """Turn a Plan response into the ``PlanResult`` the optimiser expects."""
        from advocc_ros.ros.conversions import trajectory_from_msg
        from advocc_ros.planning.worker import PlanResult, PlanStatus

        try:
            status = PlanStatus(int(res.error_code.val))
        except ValueError:
            status = PlanStatus.PLANNING_FAILED
        path = trajectory_from_msg(robot, res.trajectory) if status == PlanStatus.SUCCESS \
            else np.zeros((0, robot.nq))
        stats = {}
        if len(path) > 1:
            stats['path_length_rad'] = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        self.result = PlanResult(status, res.message, path, float(res.planning_time_s), stats)
        self.event.set()


class ShimQueries:
    """:class:`advocc_ros.attack.pfa.QueryPlanner` backed by the planner shims.

    Called from the optimiser's threads; the orchestrator's main thread (which owns every ROS
    handle) injects each query's obstacles into all shims, waits until they hold them, and plans
    on them. Queries with the same obstacles run in parallel on different shims.
    """

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))
        self.requests: queue.SimpleQueue = queue.SimpleQueue()
        self.aborted = threading.Event()

    def __call__(self, q_start, obstacles, goal, planner_id, time_budget_s, seed):
        query = _Query(q_start, tuple(obstacles), goal, planner_id, time_budget_s, seed)
        self.requests.put(query)
        while not query.event.wait(0.2):
            if self.aborted.is_set():
                raise RuntimeError('the benchmark stopped')
        return query.result


@dataclasses.dataclass
class Shim:
    """A planner shim serving this scene and what it is doing."""

    name: str
    """Fully qualified node name, e.g. ``/advocc_shim_table_pick_0``."""
    child: Child | None = None
    """None for an external shim (not ours to restart)."""
    plan: Any = None
    info: Any = None
    state: str = 'starting'
    """starting -> sync -> idle <-> busy; dead when it cannot be used any more."""
    since: float = 0.0
    future: Any = None
    trial: Any = None
    """The Trial (or PFA query) in flight."""
    deadline: float = 0.0
    info_future: Any = None
    info_at: float = 0.0
    served: int = 0


# --------------------------------------------------------------------------------------------
# The benchmark

class Orchestrator:
    """Runs ``cfg`` into ``run_dir`` (see the module docstring)."""

    def __init__(self, cfg: BenchConfig, run_dir: str | pathlib.Path,
                 heatmaps: dict[str, list[str]] | None = None, domain: int | None = None):
        self.cfg = cfg
        self.run_dir = pathlib.Path(run_dir)
        self.heatmap_sources = heatmaps or {}
        self.domain = domain
        self.env = dict(os.environ, PYTHONUNBUFFERED='1')
        if domain is not None:
            self.env['ROS_DOMAIN_ID'] = str(domain)
        self.store: RecordStore | None = None
        self.graph: Graph | None = None
        self.children: list[Child] = []
        self.restarts: collections.Counter = collections.Counter()
        self.notes: list[str] = []
        self.bar = None
        self._t0 = time.monotonic()

    # -- entry point -------------------------------------------------------------------------

    def run(self) -> dict:
        """Run (or resume) the protocol and write the report; children always stopped."""
        with run_lock(self.run_dir):
            check_run_config(self.run_dir, self.cfg)
            self.store = RecordStore(self.run_dir / 'records.jsonl')
            available = self._available_methods()
            units, self.notes = plan_units(self.cfg, available)
            self._write_config()
            old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                todo = [u for u in units if any(t.key not in self.store for t in u.trials)]
                heatmaps = self._prepare_heatmaps(todo)
                if todo:
                    self._run_units(todo, heatmaps)
                status = 'complete'
            except KeyboardInterrupt:
                status = 'interrupted'
                raise
            except BaseException:
                status = 'failed'
                raise
            finally:
                for s in old:
                    signal.signal(s, signal.SIG_IGN)  # a second Ctrl-C must not skip cleanup
                try:
                    self._shutdown()
                finally:
                    for s, handler in old.items():
                        signal.signal(s, handler)
                summary = progress_summary(self.store, units)
                if status == 'complete' and summary['missing']:
                    status = 'incomplete'
                summary = dict(summary, status=status,
                               restarts=dict(self.restarts), notes=self.notes,
                               wall_s=round(time.monotonic() - self._t0, 1))
                try:
                    write_report(self.run_dir, self.cfg, summary)
                except Exception as exc:  # the records are safe; say why the tables are not
                    log.error('writing the report failed: %s', exc)
                    if status == 'complete':
                        raise
        return summary

    def _on_signal(self, signum, frame) -> None:
        raise Interrupted(f'signal {signal.Signals(signum).name}')

    def _shutdown(self) -> None:
        if self.bar is not None:
            self.bar.close()
        for child in self.children:
            child.stop()
        self.children = []
        if self.graph is not None:
            self.graph.close()
            self.graph = None

    def _available_methods(self) -> list[str]:
        from advocc_ros.attack.api import load_method
        return [m for m in self.cfg.methods if load_method(m)]

    def _write_config(self) -> None:
        path = self.run_dir / 'config.json'
        try:  # keep the heatmaps an earlier session of this run used
            heatmaps = json.loads(path.read_text()).get('heatmaps', {})
        except (OSError, ValueError, AttributeError):
            heatmaps = {}
        heatmaps.update(self.heatmap_sources)
        data = {'config': self.cfg.to_data(), 'heatmaps': heatmaps,
                'argv': sys.argv, 'notes': self.notes}
        atomic_write_text(path, json.dumps(data, indent=2) + '\n')

    # -- heatmaps (before rclpy: building forks worker processes) ----------------------------

    def _prepare_heatmaps(self, units: list[Unit]) -> dict[str, pathlib.Path]:
        """Heatmap file per scene that still needs a generated attack."""
        from advocc_ros.heatmap.build import (HeatmapConfig, build_heatmap, load_heatmap,
                                        merge_heatmaps, save_heatmap)
        from advocc_ros.paths import scene_path
        from advocc_ros.model.scene import load_scene

        need = []
        for unit in units:
            if unit.attack is not None and unit.scene not in need and \
                    not self._attack_path(unit.attack).exists():
                need.append(unit.scene)
        out: dict[str, pathlib.Path] = {}
        for scene_name in need:
            stem = pathlib.Path(scene_path(scene_name)).stem
            sources = self.heatmap_sources.get(scene_name) or \
                self.heatmap_sources.get(stem) or self.heatmap_sources.get('*')
            target = self.run_dir / 'heatmaps' / f'{stem}.npz'
            if sources and len(sources) == 1:
                out[scene_name] = pathlib.Path(sources[0]).resolve()
                continue
            if not target.exists():
                if sources:
                    print(f'merging {len(sources)} heatmap shards for {stem}', file=sys.stderr)
                    save_heatmap(merge_heatmaps([load_heatmap(p) for p in sources]), target)
                else:
                    scene = load_scene(scene_path(scene_name))
                    hcfg = HeatmapConfig(samples=self.cfg.heatmap_samples,
                                         robot_only=self.cfg.heatmap_robot_only)
                    print(f'building the heatmap of {stem} ({hcfg.samples} samples)',
                          file=sys.stderr, flush=True)
                    save_heatmap(build_heatmap(scene, hcfg, seed=self.cfg.seed,
                                               workers=self.cfg.heatmap_workers), target)
            out[scene_name] = target
        if out:
            self.heatmap_sources = {**self.heatmap_sources,
                                    **{k: [str(v)] for k, v in out.items()}}
            self._write_config()
        return out

    # -- per scene ---------------------------------------------------------------------------

    def _run_units(self, units: list[Unit], heatmaps: dict[str, pathlib.Path]) -> None:
        from tqdm import tqdm

        self.graph = Graph(self.domain)
        planned = sum(len(u.trials) for u in units)
        done = sum(1 for u in units for t in u.trials if t.key in self.store)
        self.bar = tqdm(total=planned, initial=done, unit='trial', desc='bench',
                        file=sys.stderr, dynamic_ncols=True, smoothing=0.05)
        scenes = list(dict.fromkeys(u.scene for u in units))
        for scene_name in scenes:
            self._run_scene(scene_name, [u for u in units if u.scene == scene_name],
                            heatmaps.get(scene_name))

    def _run_scene(self, scene_name: str, units: list[Unit], heatmap: pathlib.Path | None
                   ) -> None:
        from advocc_msgs.srv import Attack, GetInfo

        from advocc_ros.paths import scene_path
        from advocc_ros.planning.worker import start_configuration
        from advocc_ros.model.robot import load_robot
        from advocc_ros.model.scene import load_scene

        self.scene_file = pathlib.Path(scene_path(scene_name)).resolve()
        self.scene = load_scene(self.scene_file)
        self.scene_name = scene_name
        self.robot = load_robot(self.scene.robot)
        self.q_init = start_configuration(self.scene, self.robot)
        stem = node_name(self.scene_file.stem)
        logs = self.run_dir / 'logs'
        self.server: Child | None = None
        self.server_clients = None
        self.heatmap_file, self.heatmap = heatmap, None
        if heatmap is not None:
            self.server = Child(f'advocc_heatmap_{stem}', 'heatmap_server',
                                {'heatmap_file': str(heatmap)}, self.env, logs)
            self.server.start()
            self.children.append(self.server)
            self.server_clients = (self.graph.client(Attack, f'/{self.server.name}/attack'),
                                   self.graph.client(GetInfo, f'/{self.server.name}/get_info'))
        self.shims: list[Shim] = []
        for i in range(self.cfg.shims):
            child = Child(f'advocc_shim_{stem}_{i}', 'planner_shim',
                          {'scene_file': str(self.scene_file)}, self.env, logs)
            child.start()
            self.children.append(child)
            self.shims.append(self._make_shim(f'/{child.name}', child))
        self._write_children()
        self.expected: dict[str, Any] = {}  # id -> SceneObject of the current injection
        self.pending: collections.deque = collections.deque()
        self._discover()
        try:
            for unit in units:
                self._run_unit(unit)
        finally:
            self._publish_remove_all()
            for child in [c for c in self.children if c is self.server
                          or any(s.child is c for s in self.shims)]:
                child.stop()
                self.children.remove(child)
            for shim in self.shims:
                self.graph.drop(shim.plan)
                self.graph.drop(shim.info)
            if self.server_clients:
                for client in self.server_clients:
                    self.graph.drop(client)

    def _make_shim(self, name: str, child: Child | None) -> Shim:
        from advocc_msgs.srv import GetInfo, Plan
        return Shim(name, child, self.graph.client(Plan, f'{name}/plan'),
                    self.graph.client(GetInfo, f'{name}/get_info'), since=time.monotonic())

    def _discover(self) -> None:
        """Add external shims of this domain (checked for the scene in state 'starting')."""
        if not self.cfg.external_shims:
            return
        known = {s.name for s in self.shims}
        # DDS discovery takes a moment; wait longer when nobody else would plan.
        deadline = time.monotonic() + (3.0 if self.cfg.shims else 30.0)
        found: list[str] = []
        while time.monotonic() < deadline and not (found and not self.cfg.shims):
            self.graph.spin(0.1)
            found = [n for n in self.graph.plan_services() if n not in known]
        for name in found:
            log.info('external shim %s', name)
            self.shims.append(self._make_shim(name, None))

    def _write_children(self) -> None:
        data = {c.name: {'pid': c.pid, 'module': c.module, 'starts': c.starts,
                         'log': str(c.log_path)} for c in self.children}
        atomic_write_text(self.run_dir / 'children.json', json.dumps(data, indent=2) + '\n')

    # -- supervision -------------------------------------------------------------------------

    def _restart(self, child: Child, why: str) -> None:
        self.restarts[child.name] += 1
        if self.restarts[child.name] > self.cfg.max_restarts:
            raise BenchError(f'{child.name} failed {self.restarts[child.name]} times ({why}); '
                             f'last output:\n{child.tail()}')
        msg = f'{child.name} {why}: restarting (#{self.restarts[child.name]})'
        log.warning(msg)
        if self.bar is not None:
            self.bar.write(f'warning: {msg}', file=sys.stderr)
        child.restart()
        self._write_children()

    def _supervise(self) -> None:
        """Restart dead children; a dead shim's trial goes back to the queue."""
        if self.server is not None and not self.server.alive():
            self._restart(self.server, f'exited with code {self.server.proc.returncode}')
            self._reset_server_clients()
        for shim in self.shims:
            if shim.child is not None and not shim.child.alive() and shim.state != 'dead':
                self._shim_down(shim, f'exited with code {shim.child.proc.returncode}')

    def _reset_server_clients(self) -> None:
        from advocc_msgs.srv import Attack, GetInfo
        for client in self.server_clients:
            self.graph.drop(client)
        self.server_clients = (self.graph.client(Attack, f'/{self.server.name}/attack'),
                               self.graph.client(GetInfo, f'/{self.server.name}/get_info'))

    def _shim_down(self, shim: Shim, why: str) -> None:
        if shim.trial is not None:
            self.pending.appendleft(shim.trial)
        if shim.future is not None:
            shim.plan.remove_pending_request(shim.future)
        shim.trial = shim.future = shim.info_future = None
        self.graph.drop(shim.plan)
        self.graph.drop(shim.info)
        if shim.child is None:
            log.warning('external shim %s %s: no longer used', shim.name, why)
            if self.bar is not None:
                self.bar.write(f'warning: external shim {shim.name} {why}: dropped',
                               file=sys.stderr)
            shim.state = 'dead'
            return
        self._restart(shim.child, why)
        fresh = self._make_shim(shim.name, shim.child)
        shim.plan, shim.info = fresh.plan, fresh.info
        shim.state, shim.since = 'starting', time.monotonic()

    # -- attacks -----------------------------------------------------------------------------

    def _attack_path(self, spec: AttackSpec) -> pathlib.Path:
        from advocc_ros.paths import scene_path
        return self.run_dir / 'attacks' / pathlib.Path(scene_path(spec.scene)).stem / \
            f'{spec.tag}.yaml'

    def _obstacles(self, spec: AttackSpec) -> tuple:
        """The attack's boxes: from the run folder, or generated now and cached there."""
        from advocc_ros.attack.api import load_obstacles, save_obstacles
        from advocc_ros.model.scene import SceneError

        path = self._attack_path(spec)
        if path.exists():
            try:
                objects, meta = load_obstacles(path)
                if meta.get('method') == spec.method and meta.get('budget') == spec.budget:
                    return objects
                log.warning('%s does not match %s: regenerating', path, spec)
            except SceneError as exc:
                log.warning('%s unreadable (%s): regenerating', path, exc)
        from advocc_ros.attack.api import CONTEXT_METHODS, load_method
        load_method(spec.method)
        if spec.method in CONTEXT_METHODS:
            objects, meta = self._generate_in_the_loop(spec)
        else:
            objects, meta = self._generate(spec)
        save_obstacles(path, meta)
        return objects

    def _generate(self, spec: AttackSpec) -> tuple[tuple, dict]:
        """Ask the heatmap server; a dead or hung server is restarted and asked again."""
        from advocc_ros.model.scene import objects_to_data
        from advocc_ros.ros.conversions import (attack_request, attack_response_data,
                                                obstacles_from_msgs)
        from advocc_ros.ros.errors import ATTACK_OK

        if self.server is None:
            raise BenchError(f'no heatmap server for {spec} (internal error)')
        request = attack_request(self.scene, spec.budget, spec.method, self.cfg.box_size_m,
                                 spec.seed)
        for attempt in range(self.cfg.max_restarts + 1):
            self._supervise()
            try:
                self._wait_server()
                t0 = time.perf_counter()
                res = self.graph.call(self.server_clients[0], request, self.cfg.attack_timeout_s,
                                      self.server.alive)
                round_trip = time.perf_counter() - t0
                break
            except CallFailed as exc:
                if self.server.alive():
                    self._restart(self.server, f'did not answer ({exc})')
                    self._reset_server_clients()
        else:
            raise BenchError(f'no attack for {spec}: the heatmap server never answered')
        data = attack_response_data(res, round_trip)
        if res.error_code.val not in ATTACK_OK:
            raise BenchError(f'attack {spec.tag} on {spec.scene} failed: {data["status"]}: '
                             f'{res.message}')
        boxes = obstacles_from_msgs(res.obstacles, prefix=spec.tag)
        meta = {'format': 'advocc_obstacles', 'version': 1, 'status': data['status'].lower(),
                'message': res.message, 'method': spec.method, 'budget': spec.budget,
                'variant': spec.variant, 'seed': spec.seed, 'planner': spec.planner,
                'planner_specific': spec.planner is not None,
                'compute_s': float(res.compute_time_s), 'round_trip_s': round(round_trip, 4),
                'masses': data['masses'], 'total_mass': data['total_mass'],
                'source': f'/{self.server.name}/attack', 'heatmap_file':
                    self.server.params['heatmap_file'],
                'scene': {'name': self.scene.name, 'file': str(self.scene_file),
                          'objects_hash': self.scene.objects_hash()},
                'objects': objects_to_data(boxes)}
        self.bar.write(f'{self.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                       f'({data["status"].lower()}, {res.compute_time_s * 1e3:.0f} ms)',
                       file=sys.stderr)
        return boxes, meta

    def _generate_in_the_loop(self, spec: AttackSpec) -> tuple[tuple, dict]:
        """PFA / PFA++: the optimiser runs in a thread; its planner queries run on the shims."""
        from advocc_ros.attack.api import AttackConfig, attack
        from advocc_ros.heatmap.build import load_heatmap
        from advocc_ros.attack.pfa import PFA_PLANNER, PfaConfig, PfaOptions
        from advocc_ros.model.scene import make_box, objects_to_data

        if self.heatmap_file is None:
            raise BenchError(f'no heatmap for {spec} (internal error)')
        if self.heatmap is None:
            self.heatmap = load_heatmap(self.heatmap_file, robot_hash=self.robot.hash)
        pcfg = PfaConfig(**dict(self.cfg.pfa, planner_id=spec.planner or PFA_PLANNER))
        queries = ShimQueries(sum(1 for s in self.shims if s.state != 'dead'))
        done = [0]

        def progress(n: int, total: int) -> None:
            done[0] = n

        outcome: dict[str, Any] = {}

        def work() -> None:
            try:
                outcome['result'] = attack(
                    self.heatmap, self.robot, self.scene.objects, self.q_init, self.scene.goal,
                    spec.budget, spec.method, AttackConfig(),
                    box_size_m=self.cfg.box_size_m or None, seed=spec.seed,
                    method_options=PfaOptions(queries, pcfg, progress))
            except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
                outcome['error'] = exc

        thread = threading.Thread(target=work, name=f'attack-{spec.tag}', daemon=True)
        self.pending = collections.deque()
        waiting: collections.deque = collections.deque()
        current = None
        sets = 0
        self.bar.write(f'{self.scene.name}: attack {spec.tag}: {pcfg.queries} planner queries '
                       f'on {queries.workers} shims', file=sys.stderr)
        thread.start()
        try:
            while thread.is_alive() or self.pending or any(s.state == 'busy'
                                                             for s in self.shims):
                self._supervise()
                while True:
                    try:
                        waiting.append(queries.requests.get_nowait())
                    except queue.Empty:
                        break
                busy = any(s.state == 'busy' for s in self.shims)
                if waiting and not self.pending and not busy and waiting[0].key != current:
                    current, sets = waiting[0].key, sets + 1
                    self._inject(tuple(make_box(f'q{sets}_{i}', o.shapes[0].pose.position_m,
                                                o.shapes[0].dims)
                                       for i, o in enumerate(waiting[0].obstacles)))
                for job in [q for q in waiting if q.key == current]:
                    waiting.remove(job)
                    self.pending.append(job)
                now = time.monotonic()
                for shim in self.shims:
                    self._step_shim(shim, now)
                if all(s.state == 'dead' for s in self.shims):
                    raise BenchError('no planner shim left for the attack\'s queries')
                self.graph.spin(0.01)
        finally:
            queries.aborted.set()
            thread.join(timeout=10)
        if 'error' in outcome:
            raise BenchError(f'attack {spec.tag} failed: {outcome["error"]!r}')
        result = outcome['result']
        if not result.status.ok:
            raise BenchError(f'attack {spec.tag} on {spec.scene} failed: {result.status.value}: '
                             f'{result.message}')
        boxes = tuple(make_box(f'{spec.tag}_{i}', o.shapes[0].pose.position_m, o.shapes[0].dims)
                      for i, o in enumerate(result.obstacles))
        stats = result.stats.get(spec.method, {})
        meta = {'format': 'advocc_obstacles', 'version': 1, 'status': result.status.value,
                'message': result.message, 'method': spec.method, 'budget': spec.budget,
                'variant': spec.variant, 'seed': spec.seed, 'planner': spec.planner,
                'planner_specific': spec.planner is not None,
                'compute_s': float(result.compute_s), 'masses': list(result.masses),
                'total_mass': float(result.total_mass),
                'source': f'{spec.method} in the orchestrator, queries on the planner shims',
                'heatmap_file': str(self.heatmap_file), 'pfa': json.loads(json.dumps(
                    stats, default=str)),
                'scene': {'name': self.scene.name, 'file': str(self.scene_file),
                          'objects_hash': self.scene.objects_hash()},
                'objects': objects_to_data(boxes)}
        self.bar.write(f'{self.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                       f'({result.status.value}, {result.compute_s:.1f} s, '
                       f'{stats.get("queries")} queries, best failure rate '
                       f'{stats.get("best_failure_rate")})', file=sys.stderr)
        return boxes, meta

    def _wait_server(self) -> None:
        from advocc_msgs.srv import GetInfo
        deadline = self.server.started_at + self.cfg.start_timeout_s
        while True:
            self._supervise()
            try:
                self.graph.call(self.server_clients[1], GetInfo.Request(), 2.0,
                                self.server.alive)
                return
            except CallFailed:
                if time.monotonic() > deadline:
                    raise BenchError(f'{self.server.name} did not come up within '
                                     f'{self.cfg.start_timeout_s:g} s; its output:\n'
                                     f'{self.server.tail()}') from None

    # -- injection ---------------------------------------------------------------------------

    def _publish(self, obj, operation) -> None:
        from advocc_ros.ros.conversions import collision_object_to_msg
        self.graph.publisher.publish(collision_object_to_msg(obj, self.scene.frame, operation))

    def _publish_remove_all(self) -> None:
        from advocc_ros.model.scene import Operation, SceneObject
        self._publish(SceneObject('', ()), Operation.REMOVE)

    def _inject(self, objects: tuple) -> None:
        """REMOVE every injected object, ADD the attack's boxes; every shim must re-sync."""
        from advocc_ros.model.scene import Operation
        self._publish_remove_all()
        for obj in objects:
            self._publish(obj, Operation.ADD)
        self.expected = {o.id: o for o in objects}
        for shim in self.shims:
            if shim.state in ('idle', 'sync'):
                shim.state, shim.since = 'sync', time.monotonic()

    def _check_info(self, shim: Shim, info: dict) -> str | None:
        """Why this shim cannot serve the scene (None: it can)."""
        static = sorted(o.id for o in self.scene.objects)
        if info.get('scene') != self.scene.name or sorted(info.get('static_objects', [])) \
                != static:
            return (f'holds scene {info.get("scene")!r} with {info.get("static_objects")}, '
                    f'not {self.scene.name!r}')
        return None

    def _step_info(self, shim: Shim, now: float) -> dict | None:
        """Poll ``get_info`` without blocking; the answer when one arrived."""
        from advocc_msgs.srv import GetInfo
        if shim.info_future is not None:
            if not shim.info_future.done():
                if now - shim.info_at > 5.0:
                    shim.info.remove_pending_request(shim.info_future)
                    shim.info_future = None
                return None
            future, shim.info_future = shim.info_future, None
            try:
                res = future.result()
                return json.loads(res.info_json) if res.success else None
            except Exception:  # noqa: BLE001 - a failed call is retried
                return None
        if now - shim.info_at >= _SYNC_POLL_S and shim.info.service_is_ready():
            shim.info_future = shim.info.call_async(GetInfo.Request())
            shim.info_at = now
        return None

    # -- trials ------------------------------------------------------------------------------

    def _run_unit(self, unit: Unit) -> None:
        from advocc_ros.model.collision import CollisionWorld

        if all(t.key in self.store for t in unit.trials):
            return
        objects = self._obstacles(unit.attack) if unit.attack is not None else ()
        self.pending = collections.deque(t for t in unit.trials if t.key not in self.store)
        self.world = CollisionWorld(self.robot, self.scene.shapes +
                                    [s for o in objects for s in o.shapes])
        self.unit = unit
        self.crashes: collections.Counter = collections.Counter()
        self._inject(objects)
        last_discovery = time.monotonic()
        while self.pending or any(s.state == 'busy' for s in self.shims):
            self._supervise()
            now = time.monotonic()
            for shim in self.shims:
                self._step_shim(shim, now)
            if all(s.state == 'dead' for s in self.shims):
                raise BenchError('no planner shim left to run the trials')
            if self.cfg.external_shims and now - last_discovery > 10.0:
                last_discovery = now
                known = {s.name for s in self.shims}
                for name in self.graph.plan_services():
                    if name not in known:
                        self.shims.append(self._make_shim(name, None))
            self.graph.spin(0.02)
        label = 'unattacked' if unit.attack is None else unit.attack.tag
        self.bar.write(f'{self.scene.name}: {label}: {len(unit.trials)} trials done',
                       file=sys.stderr)

    def _step_shim(self, shim: Shim, now: float) -> None:
        if shim.state in ('starting', 'sync'):
            info = self._step_info(shim, now)
            if shim.state == 'starting':
                if info is not None:
                    why = self._check_info(shim, info)
                    if why is None:
                        shim.state, shim.since = 'sync', now
                    elif shim.child is None:
                        log.info('external shim %s %s: not used', shim.name, why)
                        shim.state = 'dead'
                    else:
                        raise BenchError(f'{shim.name} {why}')
                elif now - shim.since > self.cfg.start_timeout_s:
                    if shim.child is None:
                        shim.state = 'dead'
                    else:
                        self._shim_down(shim, 'did not come up')
                return
            if info is not None:
                self._sync(shim, info, now)
            return
        if shim.state == 'idle' and self.pending:
            self._dispatch(shim, self.pending.popleft(), now)
        elif shim.state == 'busy':
            if shim.future.done():
                self._finish(shim)
            elif now > shim.deadline:
                self._shim_down(shim, f'did not answer a plan request within '
                                      f'{shim.deadline - shim.since:.0f} s')

    def _sync(self, shim: Shim, info: dict, now: float) -> None:
        """Idle once the shim's injected objects are exactly the current attack's."""
        from advocc_ros.model.scene import Operation, SceneObject
        have = set(info.get('injected_objects', []))
        want = set(self.expected)
        if have == want:
            shim.state = 'idle'
            return
        if now - shim.since > 2.0:  # latched history should have done it: repair
            for obj_id in sorted(have - want):
                self._publish(SceneObject(obj_id, ()), Operation.REMOVE)
            for obj_id in sorted(want - have):
                self._publish(self.expected[obj_id], Operation.ADD)  # ADD replaces: harmless
            shim.since = now
            log.info('%s re-synced: had %s, want %s', shim.name, sorted(have), sorted(want))

    def _dispatch(self, shim: Shim, job: Trial | _Query, now: float) -> None:
        from advocc_msgs.srv import Plan
        from sensor_msgs.msg import JointState

        from advocc_ros.ros.conversions import goal_region_to_msg

        if isinstance(job, _Query):
            q, goal, planner, budget = job.q_start, job.goal, job.planner_id, job.time_budget_s
        else:
            q, goal, planner = self.q_init, self.scene.goal, job.planner
            budget = self.cfg.time_budget_s
        req = Plan.Request()
        req.start_state = JointState(name=list(self.robot.joint_names),
                                     position=[float(v) for v in q])
        req.goal_region = goal_region_to_msg(goal, self.scene.frame)
        req.planner_id = planner
        req.time_budget_s = float(budget)
        req.seed = int(job.seed)
        shim.future = shim.plan.call_async(req)
        shim.trial, shim.state, shim.since = job, 'busy', now
        shim.deadline = now + budget + self.cfg.plan_timeout_margin_s

    def _finish(self, shim: Shim) -> None:
        from advocc_ros.ros.conversions import trajectory_from_msg
        from advocc_ros.ros.errors import code_name
        from advocc_ros.evaluation.metrics import trial_metrics

        future, trial = shim.future, shim.trial
        shim.future, shim.trial, shim.state = None, None, 'idle'
        shim.served += 1
        try:
            res = future.result()
        except Exception as exc:  # noqa: BLE001 - the trial is simply run again
            log.warning('%s: plan call failed (%s); trial requeued', shim.name, exc)
            self.pending.appendleft(trial)
            return
        status = code_name(res.error_code.val)
        if isinstance(trial, _Query):
            trial.done(res, self.robot)
            return
        if status in _FATAL_CODES:
            raise BenchError(f'{shim.name} rejected trial {trial.key}: {status}: {res.message}')
        if status == 'CRASH' and self.crashes[trial.key] < _CRASH_RETRIES:
            self.crashes[trial.key] += 1
            log.warning('%s: planner crashed on %s (%s); retrying', shim.name, trial.key,
                        res.message)
            self.pending.append(trial)
            return
        if self.pending and shim.state == 'idle':  # keep the shim busy while we compute
            self._dispatch(shim, self.pending.popleft(), time.monotonic())
        success = status == 'SUCCESS'
        record = {'key': trial.key, 'scene': trial.scene, 'planner': trial.planner,
                  'method': trial.method, 'budget': trial.budget, 'trial': trial.trial,
                  'seed': trial.seed, 'success': success, 'status': status,
                  'error_code': int(res.error_code.val), 'message': res.message,
                  'planning_time_s': float(res.planning_time_s),
                  'time_budget_s': float(self.cfg.time_budget_s),
                  'attack': None if self.unit.attack is None else self.unit.attack.tag,
                  'shim': shim.name, 'waypoints': len(res.trajectory.points),
                  'min_manipulability': None, 'min_clearance_rad': None, 'jds_rad': None,
                  'unix': round(time.time(), 3)}
        if success:
            path = trajectory_from_msg(self.robot, res.trajectory)
            record.update(trial_metrics(self.robot, self.world, path, self.q_init,
                                        rng=np.random.default_rng(trial.seed)))
        if self.store.append(record):
            self.bar.update(1)


# --------------------------------------------------------------------------------------------
# Report

def _attack_metas(run_dir: pathlib.Path) -> list[dict]:
    from advocc_ros.model.scene import read_yaml
    metas = []
    for path in sorted((run_dir / 'attacks').glob('*/*.yaml')):
        try:
            data = read_yaml(path)
        except Exception as exc:  # noqa: BLE001 - one bad file must not hide the tables
            log.warning('%s: %s', path, exc)
            continue
        if isinstance(data, dict):
            metas.append({k: v for k, v in data.items() if k != 'objects'} | {'path': path})
    return metas


def write_report(run_dir: str | pathlib.Path, cfg: BenchConfig, summary: dict | None = None
                 ) -> dict[str, pathlib.Path]:
    """Tables I, II, IV (+ baseline) as Markdown and CSV, figures, summary; all atomic."""
    from advocc_ros.bench import figures
    from advocc_ros.attack.api import load_obstacles
    from advocc_ros.heatmap.build import HeatmapError, load_heatmap
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import SceneError, load_scene

    run_dir = pathlib.Path(run_dir)
    store = RecordStore(run_dir / 'records.jsonl')
    rows = cell_rows(store.records.values(), cfg)
    out: dict[str, pathlib.Path] = {}

    def put(name: str, text: str) -> None:
        atomic_write_text(run_dir / name, text)
        out[name] = run_dir / name

    md1, csv1 = table1(rows, cfg)
    md2, csv2 = table2(rows, cfg)
    heatmap_meta: dict[str, dict] = {}
    heatmaps: dict[str, Any] = {}
    try:
        sources = json.loads((run_dir / 'config.json').read_text()).get('heatmaps', {})
    except (OSError, ValueError):
        sources = {}
    for scene in cfg.scenes:
        built = run_dir / 'heatmaps' / f'{pathlib.Path(scene_path(scene)).stem}.npz'
        files = sources.get(scene) or ([str(built)] if built.exists() else None)
        if not files:
            continue
        try:
            heatmaps[scene] = load_heatmap(files[0])
            heatmap_meta[scene] = heatmaps[scene].meta
        except HeatmapError as exc:
            log.warning('heatmap of %s: %s', scene, exc)
    metas = _attack_metas(run_dir)
    md4, csv4 = table4(metas, heatmap_meta)
    notes = (summary or {}).get('notes', [])
    head = (f'Time budget {cfg.time_budget_s:g} s, {cfg.trials} trials per cell planned '
            f'(`*`: fewer finished). PSR in %, SMR and CMR x10^-2, JDS in rad, PT in s.\n')
    base = baseline_table(rows, cfg)
    base = f'\n## Unattacked baseline (budget 0)\n\n{base}' if base.count('\n') > 2 else ''
    put('table1.md', f'# Table I: attack performance\n\n{head}\n{md1}{base}'
        + ''.join(f'\n- {n}' for n in notes) + ('\n' if notes else ''))
    put('table1.csv', csv1)
    put('table2.md', '# Table II: minimum budget to reach PSR <= threshold\n\n'
        'Smallest measured budget (0 = unattacked) whose PSR is at or below the threshold; '
        '"> M" when the largest measured budget M does not reach it.\n\n' + md2)
    put('table2.csv', csv2)
    put('table4.md', '# Table IV: offline and online time per method (s)\n\n'
        'Offline: heatmap build (Ours). Online: core compute time of one attack, mean over '
        'the attacks generated in this run.\n\n' + md4)
    put('table4.csv', csv4)

    # Figures: PSR vs budget per scene (one panel per planner); heatmap slice + obstacles.
    for i, scene in enumerate(cfg.scenes):
        curves = {}
        for planner in cfg.planners:
            base = rows.get((scene, planner, BASELINE, 0))
            for method in cfg.methods:
                pts = {b: rows[(scene, planner, method, b)]['psr'] for b in cfg.all_budgets
                       if (scene, planner, method, b) in rows}
                if pts and base is not None:
                    pts[0] = base['psr']
                if pts:
                    curves[(planner, method)] = pts
        stem = pathlib.Path(scene_path(scene)).stem
        if curves:
            name = f'figures/psr_vs_budget_{stem}.png'
            figures.plot_psr_vs_budget(curves, run_dir / name,
                                       title=f'Scene {i + 1} ({stem}): PSR vs budget')
            out[name] = run_dir / name
        if scene in heatmaps:
            attack_files = sorted((run_dir / 'attacks' / stem).glob('*.yaml'))
            pick = None
            for method in ['ours'] + list(cfg.methods):
                cands = [(m['budget'], m['path']) for m in metas
                         if m['path'] in attack_files and m.get('method') == method]
                if cands:
                    pick = max(cands, key=lambda c: c[0])[1]
                    break
            try:
                scene_obj = load_scene(scene_path(scene))
                obstacles = load_obstacles(pick)[0] if pick else ()
            except SceneError as exc:
                log.warning('figure of %s: %s', scene, exc)
                continue
            at = list(obstacles[0].shapes[0].pose.position_m) if obstacles else None
            name = f'figures/heatmap_{stem}.png'
            figures.plot_heatmap_slices(heatmaps[scene], run_dir / name, scene=scene_obj,
                                        obstacles=obstacles, at_m=at)
            out[name] = run_dir / name
    if summary is not None:
        put('summary.json', json.dumps(summary, indent=2) + '\n')
    return out
