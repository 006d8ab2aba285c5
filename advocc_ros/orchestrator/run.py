"""orchestrator: runs the paper's benchmark through real nodes (docs/design.md).

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
import queue
import signal
import sys
import time
from typing import Callable

import numpy as np

from advocc_ros.bench.protocol import (BenchConfig, BenchError, Trial, Unit, check_tasks,
                                       plan_units, variation_scenes)
from advocc_ros.bench.records import RecordStore, check_run_config, progress_summary, run_lock
from advocc_ros.bench.report import internal_error_summary, write_report
from advocc_ros.bench.tables import cell_rows
from advocc_ros.fileio import atomic_write_text
from advocc_ros.orchestrator.graph import Graph
from advocc_ros.orchestrator.shims import (CallFailed, PlanAnswer, PlanJob, PlanQuery, Shim,
                                           ShimPool, ShimQueries, ShimState)
from advocc_ros.orchestrator.signals import SignalGate
from advocc_ros.orchestrator.sources import AttackSources, SceneTask, prepare_heatmaps
from advocc_ros.planning.types import REQUEST_ERRORS, PlanStatus
from advocc_ros.ros.spawn import Child

log = logging.getLogger(__name__)

# Plan outcomes that say the protocol itself is wrong (not the attack): stop the benchmark.
_FATAL_CODES = frozenset(status.name for status in REQUEST_ERRORS)
_INTERNAL_ERROR_RETRIES = 2
"""A trial whose shim answers with an internal error (a crash, an exception) or whose plan call
fails is planned again this many times before the internal error is recorded."""
_INTERNAL_ERROR_CODE = int(PlanStatus.INTERNAL_ERROR)


# --------------------------------------------------------------------------------------------
# The benchmark

class Orchestrator:
    """Runs ``cfg`` into ``run_dir`` (see the module docstring); the ``RunLoop`` of its
    ``AttackSources``.

    ``pool_factory(orchestrator) -> ShimPool`` gives the planner shims of the current scene
    (``orchestrator.task``); None: ``RosShimPool`` (real nodes on a ROS graph).
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
        self.task: SceneTask | None = None
        """The scene being run."""
        self.sources: AttackSources | None = None
        """The current scene's attacks."""
        self.pending: collections.deque = collections.deque()
        """Trials (or in-the-loop queries) waiting for a shim."""
        self.unit: Unit | None = None
        self.world = None
        """``CollisionWorld`` of the current unit (scene + attack) that scores the paths."""
        self.objects_key = ''  # Scene.objects_hash() of the current unit's scene + attack
        self.goal_lists: dict = {}  # trial seed -> its GoalList (current unit)
        self.retries: collections.Counter = collections.Counter()
        self.signals = SignalGate()
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
            check_tasks(dict.fromkeys(u.scene for u in units))
            self._write_config()
            old = {s: signal.signal(s, self.signals.on_signal) for s in SignalGate.SIGNALS}
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
                errors = internal_error_summary(cell_rows(self.store.records.values(), self.cfg))
                if errors['reason'] and status in ('complete', 'incomplete'):
                    status = 'failed'
                summary = dict(summary, **errors, status=status,
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

    def _append(self, record: dict) -> None:
        """Append a trial's record; a signal meanwhile interrupts only after it is stored."""
        with self.signals.held():
            if self.store.append(record):
                self.bar.update(1)

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
        """Heatmap file per scene that still needs a generated attack, recorded in the run
        folder's config."""
        out = prepare_heatmaps(self.cfg, self.run_dir, self.heatmap_sources, units)
        if out:
            self.heatmap_sources = {**self.heatmap_sources,
                                    **{k: [str(v)] for k, v in out.items()}}
            self._write_config()
        return out

    # -- per scene ---------------------------------------------------------------------------

    def _run_units(self, units: list[Unit], heatmaps: dict[str, pathlib.Path]) -> None:
        from advocc_ros.progress import progress_bar

        if self.pool_factory is None:
            self.graph = Graph(self.domain, self.signals.held)
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
        task = self.task
        return RosShimPool(self.graph, self.cfg, task.scene, task.scene_file, task.robot,
                           self.env, self.run_dir / 'logs', self.children)

    def _run_scene(self, scene_name: str, units: list[Unit], heatmap: pathlib.Path | None
                   ) -> None:
        from advocc_ros.paths import scene_path
        from advocc_ros.kinematics.ik import start_configuration
        from advocc_ros.model.robot import load_robot
        from advocc_ros.model.scene import load_scene

        scene_file = pathlib.Path(scene_path(scene_name)).resolve()
        scene = load_scene(scene_file)
        robot = load_robot(scene.robot)
        self.task = SceneTask(scene, scene_file, robot, start_configuration(scene, robot))
        self.sources = AttackSources(self.cfg, self.run_dir, self.task, self, heatmap,
                                     self.graph, self.env, self.children)
        try:
            self.pool = (self.pool_factory or Orchestrator._ros_pool)(self)
            self._write_children()
            self.pending = collections.deque()
            self.pool.discover(wait=True)
            try:
                for unit in units:
                    self._run_unit(unit)
            finally:
                self.pool.close()
        finally:
            self.sources.close()

    def _run_unit(self, unit: Unit) -> None:
        from advocc_ros.model.collision import CollisionWorld

        if all(t.key in self.store for t in unit.trials):
            return
        objects = self.sources.obstacles(unit.attack) if unit.attack is not None else ()
        self.pending = collections.deque(t for t in unit.trials if t.key not in self.store)
        self.world = CollisionWorld(self.task.robot, self.task.scene.shapes +
                                    [s for o in objects for s in o.shapes])
        self.objects_key = self.task.scene.with_objects(list(objects)).objects_hash()
        self.unit = unit
        self.retries = collections.Counter()
        self.pool.inject(objects)
        last_discovery = t_start = time.monotonic()
        todo = len(self.pending)
        # The goal lists before the first trial: no search shares the cores with a victim.
        self.goal_lists = {seed: self._goal_list(seed)
                           for seed in dict.fromkeys(t.seed for t in self.pending)}
        try:
            while self.pending or self._busy():
                self.supervise()
                now = time.monotonic()
                for shim in list(self.pool.shims):
                    self._step_shim(shim, now)
                if all(s.state == ShimState.DEAD for s in self.pool.shims):
                    raise BenchError('no planner shim left to run the trials')
                if self.cfg.external_shims and now - last_discovery > 10.0:
                    last_discovery = now
                    self.pool.discover()
                self.pool.spin(0.02)
        finally:
            self.goal_lists = {}
        self.trial_phase_s += time.monotonic() - t_start
        self.trials_run += todo
        label = 'unattacked' if unit.attack is None else unit.attack.tag
        self.say(f'{self.task.scene.name}: {label}: {len(unit.trials)} trials done')

    def _goal_list(self, seed: int):
        """The ``GoalList`` of the trial of ``seed`` in the current unit's scene."""
        from advocc_ros.planning.goal_list import goal_list
        from advocc_ros.planning.victims import VictimConfig
        return goal_list(self.task.robot, self.world, self.task.scene.goal,
                         VictimConfig().goal_configs, seed, self.objects_key)

    def _busy(self) -> bool:
        return any(s.state == ShimState.BUSY for s in self.pool.shims)

    def live_shims(self) -> int:
        return sum(1 for s in self.pool.shims if s.state != ShimState.DEAD)

    def serve_queries(self, queries: ShimQueries, working: Callable[[], bool]) -> None:
        """Plan an in-the-loop attack's queries: the shims hold one query's obstacles at a
        time, and the queries with those obstacles run in parallel."""
        from advocc_ros.model.scene import make_box

        self.pending = collections.deque()
        waiting: collections.deque = collections.deque()
        current, sets = None, 0
        while working() or self.pending or self._busy():
            self.supervise()
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

    def restart_child(self, child: Child, why: str) -> None:
        self._count_restart(child.name, why, child.tail)
        child.restart()
        self._write_children()

    def say(self, text: str) -> None:
        self.bar.write(text, file=sys.stderr)

    def supervise(self) -> None:
        """Restart dead children; a dead shim's trial goes back to the queue."""
        self.sources.supervise()
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
            plan = PlanJob(self.task.q_init, self.task.scene.goal, job.planner,
                           self.cfg.time_budget_s, job.seed)
        self.pool.plan(shim, plan)
        shim.trial, shim.state, shim.since = job, ShimState.BUSY, now
        shim.deadline = now + plan.time_budget_s + self.cfg.plan_timeout_margin_s

    def _requeue(self, shim: Shim, exc: Exception) -> None:
        """A plan call that failed (no answer): plan the trial again, up to the retry cap."""
        job, shim.trial, shim.state = shim.trial, None, ShimState.IDLE
        shim.served += 1
        answer = PlanAnswer('INTERNAL_ERROR', _INTERNAL_ERROR_CODE, f'plan call failed: {exc}',
                            0.0, 0)
        if isinstance(job, PlanQuery):
            job.done(answer, self.task.robot.nq)
        elif not self._retry(shim, job, answer):
            self._record(shim, job, answer)

    def _retry(self, shim: Shim, trial: Trial, answer: PlanAnswer) -> bool:
        """Queue a trial that ended in an internal error again, unless it used its retries."""
        if self.retries[trial.key] >= _INTERNAL_ERROR_RETRIES:
            return False
        self.retries[trial.key] += 1
        log.warning('%s: internal error on %s (%s: %s); planned again (#%d)', shim.name,
                    trial.key, answer.status, answer.message, self.retries[trial.key])
        self.pending.append(trial)
        return True

    def _finish(self, shim: Shim, answer: PlanAnswer) -> None:
        from advocc_ros.evaluation.outcomes import INTERNAL_ERROR, outcome

        trial, shim.trial, shim.state = shim.trial, None, ShimState.IDLE
        shim.served += 1
        if isinstance(trial, PlanQuery):
            trial.done(answer, self.task.robot.nq)
            return
        if answer.status in _FATAL_CODES:
            raise BenchError(f'{shim.name} rejected trial {trial.key}: {answer.status}: '
                             f'{answer.message}')
        if outcome(answer.status) == INTERNAL_ERROR and self._retry(shim, trial, answer):
            return
        if self.pending and shim.state == ShimState.IDLE:  # keep the shim busy while we compute
            self._dispatch(shim, self.pending.popleft(), time.monotonic())
        self._record(shim, trial, answer)

    def _record(self, shim: Shim, trial: Trial, answer: PlanAnswer) -> None:
        """Score the answer's path and append the trial's record; a success whose path
        collides is recorded as an internal error, and every internal error is announced."""
        from advocc_ros.evaluation.metrics import PathInCollision, trial_metrics
        from advocc_ros.evaluation.outcomes import INTERNAL_ERROR, record_outcome
        from advocc_ros.evaluation.provenance import stamp

        success = answer.status == 'SUCCESS'
        record = {'key': trial.key, 'scene': trial.scene, 'planner': trial.planner,
                  'method': trial.method, 'budget': trial.budget, 'trial': trial.trial,
                  'seed': trial.seed, 'success': success, 'status': answer.status,
                  'error_code': answer.error_code, 'message': answer.message,
                  'planning_time_s': float(answer.planning_time_s),
                  'first_solution_s': answer.first_solution_s,
                  'time_budget_s': float(self.cfg.time_budget_s),
                  'attack': None if self.unit.attack is None else self.unit.attack.tag,
                  'shim': shim.name, 'waypoints': answer.waypoints,
                  'min_manipulability': None, 'min_clearance_rad': None, 'jds_rad': None,
                  'unix': round(time.time(), 3), **stamp()}
        # Its goal list, outside any clock (the shims' victims got the same): psr_given_goals.
        found = self.goal_lists.get(trial.seed) or self._goal_list(trial.seed)
        record.update(goal_found=found.found, goal_attempts=found.attempts)
        if success:
            try:
                record.update(trial_metrics(self.task.robot, self.world, answer.path,
                                            self.task.q_init,
                                            rng=np.random.default_rng(trial.seed)))
            except PathInCollision as exc:
                record.update(success=False, status='INTERNAL_ERROR',
                              error_code=_INTERNAL_ERROR_CODE,
                              message=f'{exc} ({answer.message})')
        if record_outcome(record) == INTERNAL_ERROR:
            self.say(f'warning: {trial.key}: internal error ({record["status"]}: '
                     f'{record["message"]}): left out of PSR')
        self._append(record)
