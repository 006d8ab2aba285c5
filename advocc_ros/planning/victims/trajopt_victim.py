"""The TrajOpt victim (``trajopt``) in a watched worker process (see ``trajopt`` for the solver).

TrajOpt's SQP runs in C++ and cannot be stopped from Python, so the victim plans in a
long-lived child process of this interpreter (``tesseract-robotics`` imports with our numpy 2),
spoken to in JSON lines through our worker's pipes (``advocc_ros.planning.worker._Worker``).
The parent samples the K goal configurations (:func:`goal_configurations`, our sampler with the
boxes, outside the budget, like MPlib's); the worker re-checks them in Tesseract's model,
restarts TrajOpt until one attempt passes both dense checks or the budget ends. A worker that
does not answer within budget + ``watchdog_margin_s`` is killed (the trial is ``TIMED_OUT``,
as for our planners: an attempt started before the deadline overran it); one that dies is an
``INTERNAL_ERROR``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pathlib
import signal
import sys
import threading
import time

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, load_robot
from advocc_ros.planning.types import PlanResult, PlanStatus, _fail, validate_request
from advocc_ros.planning.victims import Task, VictimConfig, goal_configurations
from advocc_ros.planning.worker import WorkerDied, _Worker

log = logging.getLogger(__name__)


def _worker_main() -> None:
    """Serve JSON-line plan requests on stdin; answers go to a private copy of stdout."""
    out = os.fdopen(os.dup(1), 'w', buffering=1)
    os.dup2(2, 1)  # TrajOpt's and Tesseract's prints must not corrupt the protocol
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    logging.basicConfig(level=logging.WARNING, format='trajopt worker: %(message)s')
    os.environ.setdefault('TRAJOPT_LOG_THRESH', 'ERROR')
    from advocc_ros.model.scene import scene_from_data
    from advocc_ros.planning.victims.trajopt import TrajOptConfig, TrajOptSolver

    solver: TrajOptSolver | None = None
    out.write(json.dumps({'ready': True, 'pid': os.getpid()}) + '\n')
    for line in sys.stdin:
        try:
            req = json.loads(line)
            if 'scene' in req:
                scene = scene_from_data(req['scene'], 'scene')
                robot = load_robot(scene.robot)
                config = TrajOptConfig(**req['config'])
                if solver is None or solver.robot.hash != robot.hash \
                        or solver.config != config:
                    solver = TrajOptSolver(robot, config, float(req['check_step_rad']))
                solver.set_objects(scene.shapes)
            if solver is None:
                raise ValueError('worker has no scene for this request')
            result = solver.plan(np.asarray(req['q_start'], float),
                                 np.asarray(req['goals'], float), float(req['time_s']),
                                 int(req['seed']))
            out.write(json.dumps(result.to_data()) + '\n')
        except Exception as exc:  # a bad request or a bug must not kill the worker
            log.exception('request failed')
            out.write(json.dumps({'error': repr(exc)}) + '\n')


def _worker_argv() -> tuple[list[str], dict]:
    src = str(pathlib.Path(__file__).resolve().parents[3])
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (src, env.get('PYTHONPATH')) if p)
    return [sys.executable, '-P', '-c', 'from advocc_ros.planning.victims.trajopt_victim '
            'import _worker_main; _worker_main()'], env


class TrajOptVictim:
    """``Victim`` over TrajOpt (Tesseract) in a watched worker process."""

    def __init__(self, name: str = 'trajopt', config: VictimConfig = VictimConfig(),
                 trajopt=None):
        from advocc_ros.planning.victims.trajopt import TrajOptConfig

        self.name, self.config = name, config
        self.trajopt = trajopt or TrajOptConfig()
        """``TrajOptConfig`` of the solver."""
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self._sent_scene: str | None = None
        self._model: tuple[str, RobotModel, CollisionWorld] | None = None
        self.restarts = 0

    def start(self, scene=None) -> 'TrajOptVictim':
        with self._lock:
            self._ensure_worker()
        return self

    def _ensure_worker(self) -> _Worker:
        if self._worker is None or self._worker.proc.poll() is not None:
            if self._worker is not None:
                self._worker.kill()
                self.restarts += 1
            argv, env = _worker_argv()
            self._worker = _Worker(self.config.planning.worker_start_timeout_s, argv, env,
                                   what='TrajOpt worker')
            self._sent_scene = None
        return self._worker

    def _kill_worker(self) -> None:
        if self._worker is not None:
            self._worker.kill()
            self._worker = None
            self.restarts += 1

    def _models(self, task: Task) -> tuple[RobotModel, CollisionWorld]:
        key = task.scene.objects_hash() + repr(task.scene.robot)
        if self._model is None or self._model[0] != key:
            robot = load_robot(task.scene.robot)
            self._model = (key, robot, CollisionWorld(robot, task.scene.shapes))
        return self._model[1], self._model[2]

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        robot, world = self._models(task)
        nq = robot.nq
        error = validate_request(robot, task.q_start, task.goal, 'rrtconnect', time_budget_s,
                                 self.config.planning)
        if error is not None:
            return error
        q_start = np.asarray(task.q_start, float)
        if world.in_collision(q_start):
            return _fail(PlanStatus.START_STATE_IN_COLLISION, 'start state is in collision', nq)
        t0 = time.monotonic()
        goals = goal_configurations(robot, world, task.goal, self.config.goal_configs, seed)
        stats = {'victim': self.name, 'goal_sampling_s': time.monotonic() - t0}
        if not len(goals):
            return _fail(PlanStatus.GOAL_IN_COLLISION, 'our goal sampler found no collision-free '
                         'goal configuration to hand to TrajOpt', nq, 0.0, **stats)
        request = {'q_start': q_start.tolist(), 'goals': goals.tolist(),
                   'time_s': float(time_budget_s), 'seed': int(seed)}
        return self._call(request, task, nq, time_budget_s, stats)

    def _call(self, request: dict, task: Task, nq: int, budget: float, stats: dict
              ) -> PlanResult:
        scene_key = task.scene.objects_hash() + repr(task.scene.robot)
        with self._lock:
            t_sent = time.monotonic()
            try:
                worker = self._ensure_worker()
                if self._sent_scene != scene_key:
                    request.update(scene=task.scene.to_data(),
                                   config=dataclasses.asdict(self.trajopt),
                                   check_step_rad=self.config.check_step_rad)
                t_sent = time.monotonic()
                worker.send(request)
                answer = worker.read(t_sent + budget + self.config.planning.watchdog_margin_s)
            except WorkerDied as exc:
                self._kill_worker()
                log.error('%s', exc)
                return _fail(PlanStatus.INTERNAL_ERROR, str(exc), nq,
                             time.monotonic() - t_sent, worker_died=True, **stats)
            round_trip = time.monotonic() - t_sent
            if answer is None:
                self._kill_worker()
                return _fail(PlanStatus.TIMED_OUT, f'watchdog: TrajOpt gave no answer within '
                             f'{budget:g} s + {self.config.planning.watchdog_margin_s:g} s; '
                             'worker killed', nq, round_trip, watchdog=True, outcome='timeout',
                             **stats)
            if 'error' in answer:
                return _fail(PlanStatus.INTERNAL_ERROR, f'TrajOpt worker: {answer["error"]}',
                             nq, round_trip, **stats)
            self._sent_scene = scene_key
        result = PlanResult.from_data(answer, nq)
        result.stats.update(stats, round_trip_s=round_trip)
        return result

    def close(self) -> None:
        with self._lock:
            if self._worker is not None:
                self._worker.close()
                self._worker = None

    def __del__(self):
        worker = getattr(self, '_worker', None)
        if worker is not None:
            worker.kill()


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> TrajOptVictim:
    """The registry's factory (``advocc_ros.planning.victims.make_victim('trajopt')``)."""
    return TrajOptVictim(name, config)
