"""Where a benchmark's attacks come from: the run folder's cache, the heatmap server, or a
planner-in-the-loop optimiser whose queries run on the shims."""

from __future__ import annotations

import collections
import json
import logging
import pathlib
import queue
import sys
import threading
import time
from typing import Any

from advocc_ros.bench.protocol import AttackSpec, BenchError
from advocc_ros.orchestrator.shims import CallFailed, ShimQueries, ShimState
from advocc_ros.paths import default_allowed_dirs
from advocc_ros.ros.spawn import Child, node_name

log = logging.getLogger(__name__)


class AttackSources:
    """The Orchestrator's attack half: cached, served by ``heatmap_server``, or PFA/PFA++."""

    # -- the heatmap server ------------------------------------------------------------------

    def _start_server(self, heatmap: pathlib.Path) -> None:
        stem = node_name(self.scene_file.stem)
        # The heatmap lives in the run folder, wherever --out put it: allow that folder too.
        dirs = [str(d) for d in default_allowed_dirs()] + [str(self.run_dir.resolve())]
        self.server = Child(f'advocc_heatmap_{stem}', 'heatmap_server',
                            {'heatmap_file': str(heatmap), 'allowed_dirs': dirs}, self.env,
                            self.run_dir / 'logs')
        self.server.start()
        self.children.append(self.server)
        self.server_clients = None
        self._reset_server_clients()

    def _stop_server(self) -> None:
        if self.server is None:
            return
        self.server.stop()
        self.children.remove(self.server)
        for client in self.server_clients:
            self.graph.drop(client)
        self.server = self.server_clients = None

    def _reset_server_clients(self) -> None:
        from advocc_msgs.srv import Attack, GetInfo
        for client in self.server_clients or ():
            self.graph.drop(client)
        self.server_clients = (self.graph.client(Attack, f'/{self.server.name}/attack'),
                               self.graph.client(GetInfo, f'/{self.server.name}/get_info'))

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

    # -- attacks -----------------------------------------------------------------------------

    def _attack_path(self, spec: AttackSpec) -> pathlib.Path:
        from advocc_ros.paths import scene_path
        return self.run_dir / 'attacks' / pathlib.Path(scene_path(spec.scene)).stem / \
            f'{spec.tag}.yaml'

    def _scene_meta(self) -> dict:
        return {'name': self.scene.name, 'file': str(self.scene_file),
                'objects_hash': self.scene.objects_hash()}

    @staticmethod
    def _spec_meta(spec: AttackSpec) -> dict:
        return {'variant': spec.variant, 'seed': spec.seed, 'planner': spec.planner,
                'planner_specific': spec.planner is not None}

    def _obstacles(self, spec: AttackSpec) -> tuple:
        """The attack's boxes: from the run folder, or generated now and cached there."""
        from advocc_ros.attack import load_obstacles, save_obstacles
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
        from advocc_ros.attack import REGISTRY
        if REGISTRY[spec.method].queries_planner:
            objects, meta = self._generate_in_the_loop(spec)
        else:
            objects, meta = self._generate(spec)
        save_obstacles(path, meta)
        return objects

    def _generate(self, spec: AttackSpec) -> tuple[tuple, dict]:
        """Ask the heatmap server; a dead or hung server is restarted and asked again."""
        from advocc_ros.attack.obstacles import obstacles_file_data
        from advocc_ros.ros.conversions import (attack_request, attack_response_data,
                                                obstacles_from_msgs)
        from advocc_ros.ros.errors import ATTACK_OK

        if self.server is None:
            raise BenchError(f'no heatmap server for {spec} (internal error)')
        request = attack_request(self.scene, spec.budget, spec.method, self.cfg.box_size_m,
                                 spec.seed, self.cfg.goal_policy)
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
        meta = obstacles_file_data(
            boxes, spec.method, spec.budget, data['status'].lower(), res.message,
            masses=data['masses'], total_mass=data['total_mass'],
            compute_ms=res.compute_time_s * 1e3, scene=self._scene_meta(),
            goal_policy=self.cfg.goal_policy, goal_valid_fraction=data['goal_valid_fraction'],
            solvable=data['solvable'],
            extra=dict(self._spec_meta(spec), round_trip_s=round(round_trip, 4),
                       source=f'/{self.server.name}/attack',
                       heatmap_file=self.server.params['heatmap_file']))
        self.bar.write(f'{self.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                       f'({data["status"].lower()}, {res.compute_time_s * 1e3:.0f} ms)',
                       file=sys.stderr)
        return boxes, meta

    def _generate_in_the_loop(self, spec: AttackSpec) -> tuple[tuple, dict]:
        """PFA / PFA++: the optimiser runs in a thread; its planner queries run on the shims."""
        from advocc_ros.attack import AttackConfig, attack
        from advocc_ros.heatmap import load_heatmap
        from advocc_ros.attack.pfa import PFA_PLANNER, PfaConfig, PfaOptions
        from advocc_ros.attack.obstacles import obstacles_file_data
        from advocc_ros.model.scene import make_box

        if self.heatmap_file is None:
            raise BenchError(f'no heatmap for {spec} (internal error)')
        if self.heatmap is None:
            self.heatmap = load_heatmap(self.heatmap_file, robot_hash=self.robot.hash)
        pcfg = PfaConfig(**dict(self.cfg.pfa, planner_id=spec.planner or PFA_PLANNER))
        queries = ShimQueries(sum(1 for s in self.pool.shims if s.state != ShimState.DEAD))
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
            while thread.is_alive() or self.pending or self._busy():
                self._supervise()
                while True:
                    try:
                        waiting.append(queries.requests.get_nowait())
                    except queue.Empty:
                        break
                if waiting and not self.pending and not self._busy() \
                        and waiting[0].key != current:
                    current, sets = waiting[0].key, sets + 1
                    self.pool.inject(tuple(make_box(f'q{sets}_{i}', o.shapes[0].pose.position_m,
                                                    o.shapes[0].dims)
                                           for i, o in enumerate(waiting[0].obstacles)))
                for job in [q for q in waiting if q.key == current]:
                    waiting.remove(job)
                    self.pending.append(job)
                now = time.monotonic()
                for shim in list(self.pool.shims):
                    self._step_shim(shim, now)
                if all(s.state == ShimState.DEAD for s in self.pool.shims):
                    raise BenchError('no planner shim left for the attack\'s queries')
                self.pool.spin(0.01)
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
        meta = obstacles_file_data(
            boxes, spec.method, spec.budget, result.status.value, result.message,
            result.box_size_m, result.masses, result.total_mass, result.compute_s * 1e3,
            scene=self._scene_meta(),
            extra=dict(self._spec_meta(spec),
                       source=f'{spec.method} in the orchestrator, queries on the planner shims',
                       heatmap_file=str(self.heatmap_file),
                       pfa=json.loads(json.dumps(stats, default=str))))
        self.bar.write(f'{self.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                       f'({result.status.value}, {result.compute_s:.1f} s, '
                       f'{stats.get("queries")} queries, best failure rate '
                       f'{stats.get("best_failure_rate")})', file=sys.stderr)
        return boxes, meta
