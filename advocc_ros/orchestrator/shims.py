"""The planner-shim pool: shim states, planner queries of in-the-loop attacks, and the steps
that keep every shim synchronised with the injected scene and busy with trials."""

from __future__ import annotations

import dataclasses
import enum
import json
import logging
import queue
import sys
import threading
import time
from typing import Any

import numpy as np

from advocc_ros.bench.protocol import BenchError, Trial
from advocc_ros.fileio import atomic_write_text
from advocc_ros.orchestrator.graph import CallFailed
from advocc_ros.ros.spawn import Child

log = logging.getLogger(__name__)

# Plan outcomes that say the protocol itself is wrong (not the attack): stop the benchmark.
_FATAL_CODES = {'INVALID_REQUEST', 'UNKNOWN_METHOD', 'INVALID_ROBOT_STATE',
                'INVALID_GOAL_CONSTRAINTS', 'START_STATE_IN_COLLISION'}
_CRASH_RETRIES = 2
_SYNC_POLL_S = 0.2


class ShimState(enum.StrEnum):
    """starting -> sync -> idle <-> busy; dead when it cannot be used any more."""

    STARTING = 'starting'
    SYNC = 'sync'
    IDLE = 'idle'
    BUSY = 'busy'
    DEAD = 'dead'


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
        from advocc_ros.planning import PlanResult, PlanStatus

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
    state: ShimState = ShimState.STARTING
    since: float = 0.0
    future: Any = None
    trial: Any = None
    """The Trial (or PFA query) in flight."""
    deadline: float = 0.0
    info_future: Any = None
    info_at: float = 0.0
    served: int = 0


class ShimPool:
    """The Orchestrator's shim-pool half: supervision, injection, sync, dispatch, results."""

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
            if shim.child is not None and not shim.child.alive() \
                    and shim.state != ShimState.DEAD:
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
            shim.state = ShimState.DEAD
            return
        self._restart(shim.child, why)
        fresh = self._make_shim(shim.name, shim.child)
        shim.plan, shim.info = fresh.plan, fresh.info
        shim.state, shim.since = ShimState.STARTING, time.monotonic()

    # -- attacks -----------------------------------------------------------------------------

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
            if shim.state in (ShimState.IDLE, ShimState.SYNC):
                shim.state, shim.since = ShimState.SYNC, time.monotonic()

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

    def _step_shim(self, shim: Shim, now: float) -> None:
        if shim.state in (ShimState.STARTING, ShimState.SYNC):
            info = self._step_info(shim, now)
            if shim.state == ShimState.STARTING:
                if info is not None:
                    why = self._check_info(shim, info)
                    if why is None:
                        shim.state, shim.since = ShimState.SYNC, now
                    elif shim.child is None:
                        log.info('external shim %s %s: not used', shim.name, why)
                        shim.state = ShimState.DEAD
                    else:
                        raise BenchError(f'{shim.name} {why}')
                elif now - shim.since > self.cfg.start_timeout_s:
                    if shim.child is None:
                        shim.state = ShimState.DEAD
                    else:
                        self._shim_down(shim, 'did not come up')
                return
            if info is not None:
                self._sync(shim, info, now)
            return
        if shim.state == ShimState.IDLE and self.pending:
            self._dispatch(shim, self.pending.popleft(), now)
        elif shim.state == ShimState.BUSY:
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
            shim.state = ShimState.IDLE
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
        shim.trial, shim.state, shim.since = job, ShimState.BUSY, now
        shim.deadline = now + budget + self.cfg.plan_timeout_margin_s

    def _finish(self, shim: Shim) -> None:
        from advocc_ros.ros.conversions import trajectory_from_msg
        from advocc_ros.ros.errors import code_name
        from advocc_ros.evaluation.metrics import trial_metrics

        future, trial = shim.future, shim.trial
        shim.future, shim.trial, shim.state = None, None, ShimState.IDLE
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
        if self.pending and shim.state == ShimState.IDLE:  # keep the shim busy while we compute
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
