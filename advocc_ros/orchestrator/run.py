"""orchestrator: runs the paper's benchmark through real nodes (SPEC §6, issue 6).

A plain Python program (there is no ``launch`` wheel) that, per scene,

1. starts ``heatmap_server`` (when an attack still has to be generated) and K ``planner_shim``
   processes as children, each in its own process group, on a unique node name, and waits until
   their services answer; with ``external_shims`` it also uses shims of the same ROS domain found
   by their ``*/plan`` services (other hosts), after checking they hold the same scene;
2. for each unit of the run plan (``advocc_ros.bench.plan_units``): takes the attack from the
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
import json
import logging
import os
import pathlib
import signal
import sys
import time
from typing import Callable

import numpy as np

from advocc_ros.bench.protocol import (BenchConfig, BenchError, Trial, Unit, plan_units,
                                       variation_scenes)
from advocc_ros.bench.records import RecordStore, check_run_config, progress_summary, run_lock
from advocc_ros.bench.report import write_report
from advocc_ros.fileio import atomic_write_text
from advocc_ros.orchestrator.graph import Graph
from advocc_ros.orchestrator.shims import (CallFailed, PlanAnswer, PlanJob, Shim, ShimPool,
                                           ShimState, PlanQuery)
from advocc_ros.orchestrator.sources import AttackSources
from advocc_ros.ros.spawn import Child

log = logging.getLogger(__name__)

# Plan outcomes that say the protocol itself is wrong (not the attack): stop the benchmark.
_FATAL_CODES = {'INVALID_REQUEST', 'UNKNOWN_METHOD', 'INVALID_ROBOT_STATE',
                'INVALID_GOAL_CONSTRAINTS', 'START_STATE_IN_COLLISION'}
_CRASH_RETRIES = 2


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT): stop children, keep finished trials."""


# --------------------------------------------------------------------------------------------
# The benchmark

class Orchestrator(AttackSources):
    """Runs ``cfg`` into ``run_dir`` (see the module docstring).

    ``pool_factory(orchestrator) -> ShimPool`` gives the planner shims of the current scene
    (``orchestrator.scene``, ``.robot``, ...); None: ``RosShimPool`` (real nodes on a ROS graph).
    """

    def __init__(self, cfg: BenchConfig, run_dir: str | pathlib.Path,
                 heatmaps: dict[str, list[str]] | None = None, domain: int | None = None,
                 pool_factory: Callable[['Orchestrator'], ShimPool] | None = None):
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
        self.pool_factory = pool_factory
        self.pool: ShimPool | None = None
        self.server: Child | None = None
        self._holding_signals = False
        self._held_signal: int | None = None
        self._t0 = time.monotonic()
        self.trials_run = 0
        self.trial_phase_s = 0.0
        """Trials planned by this run, and the wall time spent planning them (no node start,
        heatmap build or attack): the bench's throughput is their ratio."""

    # -- entry point -------------------------------------------------------------------------

    def run(self) -> dict:
        """Run (or resume) the protocol and write the report; children always stopped."""
        with run_lock(self.run_dir):
            check_run_config(self.run_dir, self.cfg)
            self.store = RecordStore(self.run_dir / 'records.jsonl')
            available = self._available_methods()
            units, self.notes = plan_units(self.cfg, available,
                                           variation_scenes(self.cfg, self.run_dir))
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
                               wall_s=round(time.monotonic() - self._t0, 1),
                               trials_run=self.trials_run,
                               trial_phase_s=round(self.trial_phase_s, 2),
                               trials_per_s=round(self.trials_run / self.trial_phase_s, 3)
                               if self.trial_phase_s > 0 else None)
                try:
                    write_report(self.run_dir, self.cfg, summary)
                except Exception as exc:  # the records are safe; say why the tables are not
                    log.error('writing the report failed: %s', exc)
                    if status == 'complete':
                        raise
        return summary

    def _on_signal(self, signum, frame) -> None:
        if self._holding_signals:  # raised once the record being written is in the store
            self._held_signal = signum
            return
        raise Interrupted(f'signal {signal.Signals(signum).name}')

    def _append(self, record: dict) -> None:
        """Append a trial's record; a signal meanwhile interrupts only after it is stored (an
        Interrupted between the durable write and the store's update left the summary a trial
        short of the file)."""
        self._holding_signals = True
        try:
            appended = self.store.append(record)
        finally:
            self._holding_signals = False
        if appended:
            self.bar.update(1)
        if self._held_signal is not None:
            signum, self._held_signal = self._held_signal, None
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
        from advocc_ros.attack import load_method
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
        from advocc_ros.heatmap import (HeatmapConfig, build_heatmap, load_heatmap,
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
        from advocc_ros.progress import progress_bar

        if self.pool_factory is None:
            self.graph = Graph(self.domain)
        planned = sum(len(u.trials) for u in units)
        done = sum(1 for u in units for t in u.trials if t.key in self.store)
        self.bar = progress_bar(planned, 'bench', 'trial', initial=done, file=sys.stderr,
                                smoothing=0.05)
        scenes = list(dict.fromkeys(u.scene for u in units))
        for scene_name in scenes:
            self._run_scene(scene_name, [u for u in units if u.scene == scene_name],
                            heatmaps.get(scene_name))

    def _ros_pool(self) -> ShimPool:
        from advocc_ros.orchestrator.rospool import RosShimPool
        return RosShimPool(self.graph, self.cfg, self.scene, self.scene_file, self.robot,
                           self.env, self.run_dir / 'logs', self.children)

    def _run_scene(self, scene_name: str, units: list[Unit], heatmap: pathlib.Path | None
                   ) -> None:
        from advocc_ros.paths import scene_path
        from advocc_ros.planning import start_configuration
        from advocc_ros.model.robot import load_robot
        from advocc_ros.model.scene import load_scene

        self.scene_file = pathlib.Path(scene_path(scene_name)).resolve()
        self.scene = load_scene(self.scene_file)
        self.scene_name = scene_name
        self.robot = load_robot(self.scene.robot)
        self.q_init = start_configuration(self.scene, self.robot)
        self.heatmap_file, self.heatmap = heatmap, None
        self.server = None
        if heatmap is not None:
            self._start_server(heatmap)
        self.pool = (self.pool_factory or Orchestrator._ros_pool)(self)
        self._write_children()
        self.pending: collections.deque = collections.deque()
        self.pool.discover(wait=True)
        try:
            for unit in units:
                self._run_unit(unit)
        finally:
            self.pool.close()
            self._stop_server()

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
        self.pool.inject(objects)
        last_discovery = t_start = time.monotonic()
        todo = len(self.pending)
        while self.pending or self._busy():
            self._supervise()
            now = time.monotonic()
            for shim in list(self.pool.shims):
                self._step_shim(shim, now)
            if all(s.state == ShimState.DEAD for s in self.pool.shims):
                raise BenchError('no planner shim left to run the trials')
            if self.cfg.external_shims and now - last_discovery > 10.0:
                last_discovery = now
                self.pool.discover()
            self.pool.spin(0.02)
        self.trial_phase_s += time.monotonic() - t_start
        self.trials_run += todo
        label = 'unattacked' if unit.attack is None else unit.attack.tag
        self.bar.write(f'{self.scene.name}: {label}: {len(unit.trials)} trials done',
                       file=sys.stderr)

    def _busy(self) -> bool:
        return any(s.state == ShimState.BUSY for s in self.pool.shims)

    # -- supervision -------------------------------------------------------------------------

    def _write_children(self) -> None:
        data = {c.name: {'pid': c.pid, 'module': c.module, 'starts': c.starts,
                         'log': str(c.log_path)} for c in self.children}
        atomic_write_text(self.run_dir / 'children.json', json.dumps(data, indent=2) + '\n')

    def _count_restart(self, name: str, why: str, output) -> None:
        """Count a restart of node ``name``; ``BenchError`` past ``cfg.max_restarts``."""
        self.restarts[name] += 1
        if self.restarts[name] > self.cfg.max_restarts:
            raise BenchError(f'{name} failed {self.restarts[name]} times ({why}); '
                             f'last output:\n{output()}')
        msg = f'{name} {why}: restarting (#{self.restarts[name]})'
        log.warning(msg)
        if self.bar is not None:
            self.bar.write(f'warning: {msg}', file=sys.stderr)

    def _restart(self, child: Child, why: str) -> None:
        self._count_restart(child.name, why, child.tail)
        child.restart()
        self._write_children()

    def _supervise(self) -> None:
        """Restart dead children; a dead shim's trial goes back to the queue."""
        if self.server is not None and not self.server.alive():
            self._restart(self.server, f'exited with code {self.server.proc.returncode}')
            self._reset_server_clients()
        for shim in self.pool.shims:
            if shim.state == ShimState.DEAD:
                continue
            code = self.pool.exit_code(shim)
            if code is not None:
                self._shim_down(shim, f'exited with code {code}')

    def _shim_down(self, shim: Shim, why: str) -> None:
        """Requeue the shim's trial; restart it (ours) or stop using it (external)."""
        if shim.trial is not None:
            self.pending.appendleft(shim.trial)
            shim.trial = None
        if shim.external:
            self.pool.drop(shim)
            log.warning('external shim %s %s: no longer used', shim.name, why)
            if self.bar is not None:
                self.bar.write(f'warning: external shim {shim.name} {why}: dropped',
                               file=sys.stderr)
            return
        self._count_restart(shim.name.lstrip('/'), why, lambda: self.pool.output(shim))
        self.pool.restart(shim)
        self._write_children()

    # -- trials ------------------------------------------------------------------------------

    def _step_shim(self, shim: Shim, now: float) -> None:
        if shim.state in (ShimState.STARTING, ShimState.SYNC):
            why = self.pool.sync(shim, now)
            if why is not None:
                self._shim_down(shim, why)
            return
        if shim.state == ShimState.IDLE and self.pending:
            self._dispatch(shim, self.pending.popleft(), now)
        elif shim.state == ShimState.BUSY:
            try:
                answer = self.pool.poll(shim)
            except CallFailed as exc:
                self._requeue(shim, exc)
                return
            if answer is not None:
                self._finish(shim, answer)
            elif now > shim.deadline:
                self._shim_down(shim, f'did not answer a plan request within '
                                      f'{shim.deadline - shim.since:.0f} s')

    def _dispatch(self, shim: Shim, job: Trial | PlanQuery, now: float) -> None:
        if isinstance(job, PlanQuery):
            plan = PlanJob(job.q_start, job.goal, job.planner_id, job.time_budget_s, job.seed)
        else:
            plan = PlanJob(self.q_init, self.scene.goal, job.planner, self.cfg.time_budget_s,
                           job.seed)
        self.pool.plan(shim, plan)
        shim.trial, shim.state, shim.since = job, ShimState.BUSY, now
        shim.deadline = now + plan.time_budget_s + self.cfg.plan_timeout_margin_s

    def _requeue(self, shim: Shim, exc: Exception) -> None:
        trial, shim.trial, shim.state = shim.trial, None, ShimState.IDLE
        shim.served += 1
        log.warning('%s: plan call failed (%s); trial requeued', shim.name, exc)
        self.pending.appendleft(trial)

    def _finish(self, shim: Shim, answer: PlanAnswer) -> None:
        from advocc_ros.evaluation.metrics import trial_metrics

        trial, shim.trial, shim.state = shim.trial, None, ShimState.IDLE
        shim.served += 1
        status = answer.status
        if isinstance(trial, PlanQuery):
            trial.done(answer, self.robot.nq)
            return
        if status in _FATAL_CODES:
            raise BenchError(f'{shim.name} rejected trial {trial.key}: {status}: '
                             f'{answer.message}')
        if status == 'CRASH' and self.crashes[trial.key] < _CRASH_RETRIES:
            self.crashes[trial.key] += 1
            log.warning('%s: planner crashed on %s (%s); retrying', shim.name, trial.key,
                        answer.message)
            self.pending.append(trial)
            return
        if self.pending and shim.state == ShimState.IDLE:  # keep the shim busy while we compute
            self._dispatch(shim, self.pending.popleft(), time.monotonic())
        success = status == 'SUCCESS'
        record = {'key': trial.key, 'scene': trial.scene, 'planner': trial.planner,
                  'method': trial.method, 'budget': trial.budget, 'trial': trial.trial,
                  'seed': trial.seed, 'success': success, 'status': status,
                  'error_code': answer.error_code, 'message': answer.message,
                  'planning_time_s': float(answer.planning_time_s),
                  'first_solution_s': answer.first_solution_s,
                  'time_budget_s': float(self.cfg.time_budget_s),
                  'attack': None if self.unit.attack is None else self.unit.attack.tag,
                  'shim': shim.name, 'waypoints': answer.waypoints,
                  'min_manipulability': None, 'min_clearance_rad': None, 'jds_rad': None,
                  'unix': round(time.time(), 3)}
        if success:
            record.update(trial_metrics(self.robot, self.world, answer.path, self.q_init,
                                        rng=np.random.default_rng(trial.seed)))
        self._append(record)
