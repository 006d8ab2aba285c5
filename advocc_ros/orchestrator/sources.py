"""Where a benchmark's attacks come from: the run folder's cache, the heatmap server, or a
planner-in-the-loop optimiser whose queries the run loop serves on the shims.

``AttackSources`` holds one scene's attack state (its heatmap server and clients, the loaded
heatmap) and is handed to the run loop, which it reaches only through ``RunLoop``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pathlib
import sys
import threading
import time
from typing import Any, Callable, Protocol

import numpy as np

from advocc_ros.bench.protocol import AttackSpec, BenchError
from advocc_ros.orchestrator.shims import CallFailed, ShimQueries
from advocc_ros.paths import default_allowed_dirs
from advocc_ros.ros.spawn import Child, node_name

log = logging.getLogger(__name__)


def attack_path(run_dir: pathlib.Path, spec: AttackSpec) -> pathlib.Path:
    """The run folder's cached copy of an attack."""
    from advocc_ros.paths import scene_path
    return run_dir / 'attacks' / pathlib.Path(scene_path(spec.scene)).stem / f'{spec.tag}.yaml'


def prepare_heatmaps(cfg, run_dir: pathlib.Path, given: dict[str, list[str]], units: list
                     ) -> dict[str, pathlib.Path]:
    """Heatmap file per scene that still needs a generated attack: the one given (``given``:
    scene name, file stem or ``*`` -> files), the given shards merged, or built here."""
    from advocc_ros.heatmap import (HeatmapConfig, build_heatmap, load_heatmap,
                                    merge_heatmaps, save_heatmap)
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import load_scene

    need = []
    for unit in units:
        if unit.attack is not None and unit.scene not in need and \
                not attack_path(run_dir, unit.attack).exists():
            need.append(unit.scene)
    out: dict[str, pathlib.Path] = {}
    for scene_name in need:
        stem = pathlib.Path(scene_path(scene_name)).stem
        sources = given.get(scene_name) or given.get(stem) or given.get('*')
        target = run_dir / 'heatmaps' / f'{stem}.npz'
        if sources and len(sources) == 1:
            out[scene_name] = pathlib.Path(sources[0]).resolve()
            continue
        if not target.exists():
            if sources:
                print(f'merging {len(sources)} heatmap shards for {stem}', file=sys.stderr)
                save_heatmap(merge_heatmaps([load_heatmap(p) for p in sources]), target)
            else:
                scene = load_scene(scene_path(scene_name))
                hcfg = HeatmapConfig(samples=cfg.heatmap_samples,
                                     robot_only=cfg.heatmap_robot_only)
                print(f'building the heatmap of {stem} ({hcfg.samples} samples)',
                      file=sys.stderr, flush=True)
                save_heatmap(build_heatmap(scene, hcfg, seed=cfg.seed,
                                           workers=cfg.heatmap_workers), target)
        out[scene_name] = target
    return out


def server_allowed_dirs(run_dir: pathlib.Path, heatmap: pathlib.Path) -> list[str]:
    """Where the bench's heatmap server may read: the node defaults, the run folder (merged and
    built heatmaps, wherever --out put it) and the folder of the heatmap file the user gave."""
    return [str(d) for d in default_allowed_dirs()] + [
        str(pathlib.Path(run_dir).resolve()), str(pathlib.Path(heatmap).resolve().parent)]


@dataclasses.dataclass(frozen=True)
class SceneTask:
    """The scene a benchmark is running and its task."""

    scene: Any
    """``advocc_ros.model.scene.Scene``."""
    scene_file: pathlib.Path
    robot: Any
    """``advocc_ros.model.robot.RobotModel`` of the scene."""
    q_init: np.ndarray
    """Start configuration (nq,) [rad]."""


class RunLoop(Protocol):
    """What the attack sources need from the benchmark's run loop."""

    def supervise(self) -> None:
        """Restart dead children (the heatmap server too, through ``AttackSources.supervise``)."""

    def restart_child(self, child: Child, why: str) -> None:
        """Count a restart of ``child`` (``BenchError`` past the limit) and restart it."""

    def say(self, text: str) -> None:
        """A progress line for the user."""

    def serve_queries(self, queries: ShimQueries, working: Callable[[], bool]) -> None:
        """Plan the optimiser's queries on the shims while ``working()`` or queries remain."""

    def live_shims(self) -> int:
        """Shims that can still plan."""


def server_parameters(cfg, run_dir: pathlib.Path, heatmap: pathlib.Path) -> dict:
    """The parameters of the heatmap server a benchmark starts: the heatmap and the folders
    it may read, the protocol's victim margin and ``task`` options, and ``search_witness``:
    the tables count certified attacks, so every attack gets the task's witness (found once
    per scene in the server, cached), not only solvable ones."""
    from advocc_ros.nodes.heatmap_server import task_parameters
    return {'heatmap_file': str(heatmap), 'allowed_dirs': server_allowed_dirs(run_dir, heatmap),
            'search_witness': True, 'victim_margin_m': float(cfg.victim_margin_m),
            **task_parameters(cfg.task)}


class AttackSources:
    """One scene's attacks: cached in the run folder, served by ``heatmap_server`` (started
    here when ``heatmap_file`` is given and ``graph`` is a ROS graph), or PFA/PFA++."""

    def __init__(self, cfg, run_dir: pathlib.Path, task: SceneTask, loop: RunLoop,
                 heatmap_file: pathlib.Path | None = None, graph=None, env: dict | None = None,
                 children: list[Child] | None = None):
        self.cfg, self.run_dir, self.task, self.loop = cfg, run_dir, task, loop
        self.heatmap_file = heatmap_file
        self.heatmap = None
        """The heatmap, loaded on the first in-the-loop attack."""
        self.graph, self.env = graph, env or {}
        self.children = children if children is not None else []
        self.server: Child | None = None
        self.server_clients: tuple | None = None
        if heatmap_file is not None and graph is not None:
            self._start_server(heatmap_file)

    # -- the heatmap server ------------------------------------------------------------------

    def _start_server(self, heatmap: pathlib.Path) -> None:
        stem = node_name(self.task.scene_file.stem)
        self.server = Child(f'advocc_heatmap_{stem}', 'heatmap_server',
                            server_parameters(self.cfg, self.run_dir, heatmap),
                            self.env, self.run_dir / 'logs')
        self.server.start()
        self.children.append(self.server)
        self._reset_server_clients()

    def close(self) -> None:
        """Stop the heatmap server."""
        if self.server is None:
            return
        self.server.stop()
        self.children.remove(self.server)
        for client in self.server_clients:
            self.graph.drop(client)
        self.server = self.server_clients = None

    def supervise(self) -> None:
        """Restart a heatmap server that died."""
        if self.server is not None and not self.server.alive():
            self.loop.restart_child(self.server,
                                    f'exited with code {self.server.exit_code()}')
            self._reset_server_clients()

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
            self.loop.supervise()
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

    def _scene_meta(self) -> dict:
        return {'name': self.task.scene.name, 'file': str(self.task.scene_file),
                'objects_hash': self.task.scene.objects_hash()}

    def _spec_meta(self, spec: AttackSpec) -> dict:
        meta = {'variant': spec.variant, 'seed': spec.seed, 'planner': spec.planner,
                'planner_specific': spec.planner is not None}
        if spec.method == 'task':
            from advocc_ros.attack.task import task_options
            meta['task_options'] = dataclasses.asdict(task_options(self.cfg.task))
        return meta

    def obstacles(self, spec: AttackSpec) -> tuple:
        """The attack's boxes: from the run folder, or generated now and cached there."""
        from advocc_ros.attack import load_obstacles, save_obstacles
        from advocc_ros.model.pose import SceneError

        path = attack_path(self.run_dir, spec)
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
        request = attack_request(self.task.scene, spec.budget, spec.method, self.cfg.box_size_m,
                                 spec.seed, self.cfg.goal_policy)
        for attempt in range(self.cfg.max_restarts + 1):
            self.loop.supervise()
            try:
                self._wait_server()
                t0 = time.perf_counter()
                # Resent after a quarter of the timeout (an attack for a seed is the same
                # twice): a lost first answer then costs that, not a timeout and a restart.
                res = self.graph.call(self.server_clients[0], request, self.cfg.attack_timeout_s,
                                      self.server.alive, resend_s=self.cfg.attack_timeout_s / 4)
                round_trip = time.perf_counter() - t0
                break
            except CallFailed as exc:
                if self.server.alive():
                    self.loop.restart_child(self.server, f'did not answer ({exc})')
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
        self.loop.say(f'{self.task.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                      f'({data["status"].lower()}, {res.compute_time_s * 1e3:.0f} ms)')
        return boxes, meta

    def _generate_in_the_loop(self, spec: AttackSpec) -> tuple[tuple, dict]:
        """PFA / PFA++: the optimiser runs in a thread; the run loop serves its planner queries
        on the shims."""
        from advocc_ros.attack import AttackConfig, attack
        from advocc_ros.heatmap import load_heatmap
        from advocc_ros.attack.pfa import PFA_PLANNER, PfaConfig, PfaOptions
        from advocc_ros.attack.obstacles import obstacles_file_data
        from advocc_ros.model.scene import make_box

        if self.heatmap_file is None:
            raise BenchError(f'no heatmap for {spec} (internal error)')
        if self.heatmap is None:
            self.heatmap = load_heatmap(self.heatmap_file, robot_hash=self.task.robot.hash)
        pcfg = PfaConfig(**dict(self.cfg.pfa, planner_id=spec.planner or PFA_PLANNER))
        queries = ShimQueries(self.loop.live_shims())
        task = self.task
        outcome: dict[str, Any] = {}

        def work() -> None:
            try:
                outcome['result'] = attack(  # no verdict: its file records none
                    self.heatmap, task.robot, task.scene.objects, task.q_init, task.scene.goal,
                    spec.budget, spec.method,
                    AttackConfig(victim_margin_m=float(self.cfg.victim_margin_m)),
                    box_size_m=self.cfg.box_size_m or None, seed=spec.seed, certify=False,
                    method_options=PfaOptions(queries, pcfg, lambda n, total: None))
            except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
                outcome['error'] = exc

        thread = threading.Thread(target=work, name=f'attack-{spec.tag}', daemon=True)
        self.loop.say(f'{task.scene.name}: attack {spec.tag}: {pcfg.queries} planner queries '
                      f'on {queries.workers} shims')
        thread.start()
        try:
            self.loop.serve_queries(queries, thread.is_alive)
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
        self.loop.say(f'{task.scene.name}: attack {spec.tag}: {len(boxes)} boxes '
                      f'({result.status.value}, {result.compute_s:.1f} s, '
                      f'{stats.get("queries")} queries, best failure rate '
                      f'{stats.get("best_failure_rate")})')
        return boxes, meta
