"""Motion planning with OMPL to tolerance-aware goal regions, run in a watched worker process.

The victim side of the evaluation (paper §V-A; docs/design.md): OMPL geometric planners over
the arm joints (``RealVectorStateSpace`` with the joint limits), a validity checker built on
``CollisionWorld`` (SRDF self-collision + scene), and a goal region reached by sampling goal
configurations with damped-least-squares IK inside the region.

Why a worker process. OMPL's ``solve`` runs in C++ and cannot be interrupted from Python; a
planner that ignores its termination condition, or a pathological scene (a huge mesh), would hold
the caller forever. ``Planner`` therefore runs every request in one long-lived child process
(``python -c 'from advocc_ros.planning.worker import worker_main; worker_main()'``) that it
reuses across requests (imports and the robot model load once; the per-request cost is one
JSON line each way, measured ~1 ms). The parent waits for the answer with a watchdog deadline of
``time_budget_s + watchdog_margin_s``; past it, the child is killed (SIGKILL), the request is
reported as ``TIMED_OUT`` with a message saying so, and a fresh child is started on the next
request. A child that dies on its own, and an exception while serving a request, are reported
as ``INTERNAL_ERROR``: they say nothing about the scene, so they must never read as a planning
failure (an attack win). Requests and answers are JSON lines on the child's stdin and a private
duplicate of its stdout (fd 1 itself is redirected to stderr so that C++ output cannot corrupt
the protocol); nothing is unpickled.

For diagnostics only, ``ADVOCC_PLANNING_FAULT`` in the worker's environment injects a fault into
the plan requests of chosen seeds: ``raise:3,5`` raises inside the request, ``kill:3`` makes the
worker SIGKILL itself mid-request (the tests of the INTERNAL_ERROR path use both).

Why ompl 1.7.0 and how PRM* stays bounded. ompl 2.0.1's PRM/PRM* start a second C++ thread in
``solve`` that calls the Python validity checker while the first thread holds the GIL and PRM's
graph mutex, which deadlocks. The 1.7.0 Boost.Python bindings bind PRM's single-threaded
``solve``, so ``og.PRMstar`` here is OMPL's real PRM* and it honours the termination condition
(measured: a 1.0 s budget returns after ~1.0 s). The watchdog is the second line of defence.

OMPL's RNG can be seeded only before its first use in a process, so ``seed`` seeds the IK goal
sampling per request and OMPL once per worker (with the first request's seed): trials are
independent and statistically reproducible, not bit-reproducible.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pathlib
import selectors
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

from advocc_ros.model.robot import RobotError, load_robot
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import Scene, scene_from_data
from advocc_ros.planning.solve import ompl_modules, ompl_version, solve
from advocc_ros.planning.types import (PlanningConfig, PlanResult, PlanStatus, failed,
                                       validate_request)

log = logging.getLogger(__name__)

FAULT_ENV = 'ADVOCC_PLANNING_FAULT'


class InjectedFault(RuntimeError):
    """The diagnostic exception of ``FAULT_ENV`` (logged without a traceback)."""


def _inject_fault(seed: int) -> None:
    """Raise or die here if ``FAULT_ENV`` asks for it for this seed (see the module docstring)."""
    spec = os.environ.get(FAULT_ENV, '')
    if not spec:
        return
    kind, _, seeds = spec.partition(':')
    try:
        chosen = {int(v) for v in seeds.split(',')}
    except ValueError:
        chosen = None
    if kind not in ('raise', 'kill') or chosen is None:
        raise ValueError(f'{FAULT_ENV}={spec!r}: expected raise:SEED[,SEED...] or '
                         'kill:SEED[,SEED...]')
    if seed not in chosen:
        return
    if kind == 'kill':
        os.kill(os.getpid(), signal.SIGKILL)
    raise InjectedFault(f'fault injected by {FAULT_ENV}={spec}')


# --------------------------------------------------------------------------------------------
# The worker process

def worker_main() -> None:
    """Serve JSON-line plan requests on stdin; answers go to a private copy of stdout."""
    out = os.fdopen(os.dup(1), 'w', buffering=1)
    os.dup2(2, 1)  # C++ output on fd 1 must not corrupt the protocol
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    logging.basicConfig(level=logging.WARNING, format='planning worker: %(message)s')
    from advocc_ros.model.collision import CollisionWorld
    ob, og, ou = ompl_modules()
    ou.setLogLevel(ou.LOG_ERROR)
    cache: dict[str, Any] = {}

    def reply(data: dict) -> None:
        out.write(json.dumps(data) + '\n')

    reply({'ready': True, 'pid': os.getpid(), 'ompl': ompl_version()})
    for line in sys.stdin:
        try:
            req = json.loads(line)
            op = req.get('op')
            if op == 'stall':  # diagnostic: a request that never answers (tests the watchdog)
                time.sleep(float(req['seconds']))
                reply({'stalled': True})
                continue
            if op != 'plan':
                raise ValueError(f'unknown op {op!r}')
            if 'scene' in req:
                scene = scene_from_data(req['scene'], 'scene')
                robot = load_robot(scene.robot)
                cache.update(key=req['scene_key'], robot=robot,
                             world=CollisionWorld(robot, scene.shapes))
            if cache.get('key') != req['scene_key']:
                raise ValueError('worker has no scene for this request')
            config = PlanningConfig(**{k: tuple(v) if isinstance(v, list) else v
                                       for k, v in req['config'].items()})
            _inject_fault(int(req['seed']))
            result = solve(cache['robot'], cache['world'],
                           np.asarray(req['q_start'], float),
                           GoalRegion.from_data(req['goal'], 'goal'), req['planner_id'],
                           float(req['time_budget_s']), int(req['seed']), config,
                           req.get('goal_configs'))
            reply(result.to_data())
        except Exception as exc:  # a bad request or a bug must not kill the worker
            if isinstance(exc, InjectedFault):
                log.error('request failed: %s', exc)
            else:
                log.exception('request failed')
            reply({'status': int(PlanStatus.INTERNAL_ERROR), 'message': f'worker: {exc!r}',
                   'path': [], 'planning_time_s': 0.0, 'stats': {}})


class WorkerDied(RuntimeError):
    """The worker process exited or could not start."""


def _our_worker_argv() -> tuple[list[str], dict]:
    """Command and environment of our OMPL worker (this interpreter, this source tree)."""
    src = str(pathlib.Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (src, env.get('PYTHONPATH')) if p)
    # -P: the working directory must not shadow the parent's code (a checkout's cwd).
    return [sys.executable, '-P', '-c', 'from advocc_ros.planning.worker import worker_main; '
            'worker_main()'], env


class WorkerProcess:
    """One child process and its pipes. ``argv``/``env``: another JSON-line worker (an outside
    victim's, in its own interpreter); by default our OMPL worker."""

    def __init__(self, timeout_s: float, argv: list[str] | None = None,
                 env: dict | None = None, what: str = 'planning worker'):
        if argv is None:
            argv, env = _our_worker_argv()
        self.what = what
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     env=env, close_fds=True)
        self._buf = b''
        self.scene_key: str | None = None
        try:
            hello = self.read(time.monotonic() + timeout_s)
        except BaseException:
            self.kill()
            raise
        if hello is None or not hello.get('ready'):
            self.kill()
            raise WorkerDied(f'{what} did not start within {timeout_s:g} s')
        self.pid = int(hello['pid'])
        self.ompl_version: str | None = hello.get('ompl')
        """The OMPL version the worker's interpreter imports (None: it reported none)."""

    def send(self, data: dict) -> None:
        try:
            self.proc.stdin.write((json.dumps(data) + '\n').encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            raise WorkerDied(f'{self.what} is gone ({exc})') from None

    def read(self, deadline: float) -> dict | None:
        """Next answer, or None if ``deadline`` (monotonic) passes first."""
        fd = self.proc.stdout.fileno()
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while b'\n' not in self._buf:
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    return None
                chunk = os.read(fd, 1 << 16)
                if not chunk:
                    code = self.proc.wait()
                    how = (f'was killed by {signal.Signals(-code).name}' if code < 0
                           else f'exited with code {code}')
                    raise WorkerDied(f'{self.what} {how}')
                self._buf += chunk
        line, self._buf = self._buf.split(b'\n', 1)
        return json.loads(line)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            try:
                pipe.close()
            except OSError:
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout_s)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.kill()


class WorkerSlot:
    """A planner's one worker process: started on demand, replaced after it died or was killed
    (``restarts`` counts those), closed at the end and killed if the planner is forgotten.
    The start function is passed per call, so the slot keeps no reference to its planner."""

    def __init__(self):
        self.worker: WorkerProcess | None = None
        self.restarts = 0

    def ensure(self, start) -> tuple[WorkerProcess, bool]:
        """The live worker, and whether ``start()`` made it now."""
        if self.worker is not None and self.worker.proc.poll() is None:
            return self.worker, False
        if self.worker is not None:
            self.worker.kill()
            self.restarts += 1
        self.worker = start()
        return self.worker, True

    def kill(self) -> None:
        """Kill the worker (a watchdog or a broken answer): the next request starts another."""
        if self.worker is not None:
            self.worker.kill()
            self.worker = None
            self.restarts += 1

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
            self.worker = None

    def __del__(self):
        if self.worker is not None:
            self.worker.kill()


class Planner:
    """Plans in a scene with one reusable, watched worker process (see the module docstring).

    Thread-safe: concurrent ``plan`` calls are served one after the other, and ``set_scene``
    waits for the request in flight (a request never pairs one scene's key with another's
    objects). Use one ``Planner`` per parallel stream of requests (each owns a process).
    """

    def __init__(self, scene: Scene, config: PlanningConfig = PlanningConfig(), command=None):
        """``command() -> (argv, env)``: run the worker in another interpreter (the OMPL 2
        victims' ``.venv-ompl2``); None: this interpreter, our OMPL 1.7."""
        self.config = config
        self.command = command
        self.robot = load_robot(scene.robot)
        self._lock = threading.Lock()
        self._slot = WorkerSlot()
        self.set_scene(scene)
        self.requests = 0
        self.ompl_version: str | None = None
        """The OMPL version the last worker started reported (None before the first)."""

    def set_scene(self, scene: Scene) -> None:
        """Scene for the next requests (objects may change; the robot may not)."""
        if scene.robot != self.robot.spec:
            raise RobotError('a Planner plans for one robot; create another for a new robot')
        data = scene.to_data()
        key = json.dumps([scene.objects_hash(), data['robot']], sort_keys=True)
        with self._lock:
            self._scene, self._scene_data, self._scene_key = scene, data, key

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def worker_pid(self) -> int | None:
        return self._slot.worker.pid if self._slot.worker else None

    @property
    def restarts(self) -> int:
        """Workers replaced after they died or were killed."""
        return self._slot.restarts

    def start(self) -> 'Planner':
        """Start the worker now (otherwise the first request does)."""
        with self._lock:
            self._ensure_worker()
        return self

    def _ensure_worker(self) -> WorkerProcess:
        worker, fresh = self._slot.ensure(lambda: WorkerProcess(
            self.config.worker_start_timeout_s, *(self.command() if self.command else ())))
        if fresh:
            log.debug('planning worker %d started', worker.pid)
            self.ompl_version = worker.ompl_version
        return worker

    def plan(self, q_start, goal: GoalRegion, planner_id: str = 'rrtconnect',
             time_budget_s: float | None = None, seed: int = 0, goal_configs=None
             ) -> PlanResult:
        """Plan from ``q_start`` (nq,) to any valid configuration with FK inside ``goal``, or,
        with ``goal_configs`` (K, nq), to one of those (``solve``'s goal-list option)."""
        budget = self.config.time_budget_s if time_budget_s is None else time_budget_s
        error = validate_request(self.robot, q_start, goal, planner_id, budget, self.config)
        if error is not None:
            return error
        request = {'op': 'plan', 'q_start': np.asarray(q_start, float).tolist(),
                   'goal': goal.to_data(), 'planner_id': planner_id,
                   'time_budget_s': float(budget), 'seed': int(seed),
                   'config': dataclasses.asdict(self.config)}
        if goal_configs is not None:
            request['goal_configs'] = np.asarray(goal_configs, float).tolist()
        with self._lock:
            self.requests += 1
            request['scene_key'] = self._scene_key
            return self._call(request, budget)

    def _call(self, request: dict, budget: float) -> PlanResult:
        nq = self.robot.nq
        t0 = time.monotonic()
        try:
            worker = self._ensure_worker()
            if worker.scene_key != request['scene_key']:
                request = dict(request, scene=self._scene_data)
                worker.scene_key = request['scene_key']
            t_sent = time.monotonic()
            worker.send(request)
            answer = worker.read(t_sent + budget + self.config.watchdog_margin_s)
        except WorkerDied as exc:
            self._slot.kill()
            log.error('%s', exc)
            return failed(PlanStatus.INTERNAL_ERROR, str(exc), nq, time.monotonic() - t0,
                          worker_died=True)
        round_trip = time.monotonic() - t_sent
        if answer is None:
            self._slot.kill()
            msg = (f'watchdog: no answer within budget {budget:g} s + margin '
                   f'{self.config.watchdog_margin_s:g} s; worker killed')
            log.error('%s', msg)
            return failed(PlanStatus.TIMED_OUT, msg, nq, round_trip, watchdog=True)
        if 'status' not in answer:
            return failed(PlanStatus.INTERNAL_ERROR, f'unexpected worker answer {answer}', nq)
        result = PlanResult.from_data(answer, nq)
        result.stats['round_trip_s'] = round_trip
        result.stats['overhead_s'] = round_trip - result.planning_time_s
        return result

    def stall(self, seconds: float, watchdog_s: float) -> PlanResult:
        """Diagnostic: a request that holds the worker ``seconds``, watched for ``watchdog_s``
        as a plan is (``TIMED_OUT`` with the worker killed past it): tests the watchdog."""
        with self._lock:
            worker = self._ensure_worker()
            worker.send({'op': 'stall', 'seconds': seconds})
            t0 = time.monotonic()
            answer = worker.read(t0 + watchdog_s)
            if answer is None:
                self._slot.kill()
                return failed(PlanStatus.TIMED_OUT, 'watchdog: worker killed', self.robot.nq,
                              time.monotonic() - t0, watchdog=True)
            return failed(PlanStatus.SUCCESS, 'stall answered', self.robot.nq,
                          time.monotonic() - t0)

    def close(self) -> None:
        with self._lock:
            self._slot.close()

    def __enter__(self) -> 'Planner':
        return self

    def __exit__(self, *exc) -> None:
        self.close()
