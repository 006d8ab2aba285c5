"""What every outside victim's parent side does: one watched worker, the goal list, the checks.

An outside victim (MPlib, TrajOpt) plans in its own worker process (its own interpreter when
its dependencies conflict with ours), spoken to in JSON lines through our worker's pipes
(``advocc_ros.planning.worker.WorkerProcess``). The parent keeps what the victim does not have: the
request's checks (``validate_request``, the start in our model), the goal list (the task's, or
K sampled with the boxes from the trial's seed, outside the budget), and our collision model to
re-validate the answer. A worker that does not answer within budget + margin is killed (the
trial is ``TIMED_OUT``, as for our planners); one that dies or raises is an ``INTERNAL_ERROR``.
Subclasses say how to start their worker, what to send it when the robot or scene changes, and
how to read its answer (``worker_command``, ``setup_fields``, ``plan_result``), with the
parent's ``models``, ``call``, ``preload`` and ``checked_path`` at hand.
"""

from __future__ import annotations

import logging
import os
import pathlib
import threading
import time

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, load_robot
from advocc_ros.planning.types import PlanResult, PlanStatus, failed, validate_request
from advocc_ros.planning.victims.base import Task, VictimConfig, first_collision_along
from advocc_ros.planning.worker import WorkerDied, WorkerSlot, WorkerProcess

_CHECKOUT = pathlib.Path(__file__).resolve().parents[3]

log = logging.getLogger(__name__)


class VictimUnavailable(ValueError):
    """The victim's interpreter or library is not installed."""


def venv_python(configured: str, env: str, venv: str, label: str) -> pathlib.Path:
    """An outside victim's interpreter: ``configured`` (its ``VictimConfig`` field), else
    ``$env``, else the checkout's ``venv``; ``VictimUnavailable`` saying how to make it."""
    path = pathlib.Path(configured or os.environ.get(env) or _CHECKOUT / venv / 'bin' / 'python')
    if not path.is_file():
        raise VictimUnavailable(f'{label}: no interpreter at {path}; run `make install` '
                                f'(it creates {venv}) or set {env}')
    return path


class OutsideVictim:
    """``Victim`` over one watched worker process; see the module docstring."""

    label = 'outside victim'
    """Name in messages (``MPlib``, ``TrajOpt``)."""

    def __init__(self, name: str, config: VictimConfig = VictimConfig()):
        self.name, self.config = name, config
        self._lock = threading.Lock()
        self._slot = WorkerSlot()
        self._sent: str | None = None
        self._model: tuple[str, RobotModel, CollisionWorld] | None = None

    # -- what a subclass provides ------------------------------------------------------------

    def worker_command(self) -> tuple[list[str], dict]:
        """argv and environment of the worker process."""
        raise NotImplementedError

    def setup_fields(self, task: Task, robot: RobotModel) -> dict:
        """Fields sent with a request when the worker has not seen this robot and scene."""
        raise NotImplementedError

    def plan_result(self, answer: dict, robot: RobotModel, world: CollisionWorld,
                    q_start: np.ndarray, goals: np.ndarray, budget: float, stats: dict
                    ) -> PlanResult:
        """The worker's answer to a plan request as a ``PlanResult`` (re-validated)."""
        raise NotImplementedError

    # -- the protocol ------------------------------------------------------------------------

    def start(self, scene=None) -> 'OutsideVictim':
        with self._lock:
            self._ensure_worker()
        return self

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        robot, world = self.models(task)
        nq = robot.nq
        error = validate_request(robot, task.q_start, task.goal, 'rrtconnect', time_budget_s,
                                 self.config.planning)
        if error is not None:
            return error
        q_start = np.asarray(task.q_start, float)
        if world.in_collision(q_start):
            return failed(PlanStatus.START_STATE_IN_COLLISION, 'start state is in collision', nq)
        found = task.goal_list(robot, world, self.config.goal_configs, seed)
        goals = found.configs
        stats = {'victim': self.name, 'goal_sampling_s': found.time_s, **found.stats()}
        if not found.found:
            return failed(PlanStatus.GOAL_IN_COLLISION, 'no goal found: our goal sampler found no '
                          f'collision-free goal configuration to hand to {self.label} in '
                          f'{found.attempts} IK attempts ({found.time_s:.1f} s, before the clock)',
                          nq, 0.0, **stats)
        request = {'op': 'plan', 'q_start': q_start.tolist(), 'goals': goals.tolist(),
                   'time_s': float(time_budget_s), 'seed': int(seed),
                   'check_step_rad': self.config.check_step_rad}
        answer = self.call(request, task, robot, time_budget_s, stats)
        if isinstance(answer, PlanResult):
            return answer
        return self.plan_result(answer, robot, world, q_start, goals, time_budget_s, stats)

    def checked_path(self, path: np.ndarray, world: CollisionWorld, q_start: np.ndarray,
                     goals: np.ndarray, elapsed: float, stats: dict, own_collision: int = -1
                     ) -> PlanResult | None:
        """None if a solution's ``path`` runs from the start to one of the given goals and is
        free in the victim's model (``own_collision``: its first colliding state every
        ``check_step_rad``, -1: none) and in ours; else the failure, in this order: not from
        the start to a goal (an internal error), colliding in its own model (its motion check
        stepped over an obstacle: ``INVALID_MOTION_PLAN``), colliding in ours only
        (``MODEL_MISMATCH``)."""
        nq, step = world.robot.nq, self.config.check_step_rad
        if len(path) < 2 or not np.allclose(path[0], q_start, atol=1e-6) or not np.any(
                np.all(np.isclose(goals, path[-1], atol=1e-6), axis=1)):
            return failed(PlanStatus.INTERNAL_ERROR, f'{self.label}\'s path does not run from '
                          'the start to a goal configuration', nq, elapsed, **stats)
        if own_collision >= 0:
            return failed(PlanStatus.INVALID_MOTION_PLAN, f'{self.label}: its solution collides '
                          f'in its own model at state {own_collision} (checked every {step:g} '
                          'rad): its motion check stepped over an obstacle', nq, elapsed,
                          **stats)
        ours = first_collision_along(world, path, step)
        if ours >= 0:
            return failed(PlanStatus.MODEL_MISMATCH, f'{self.label}: its solution is free in its '
                          f'own model but collides in ours (convex hulls) at state {ours} '
                          f'(checked every {step:g} rad)', nq, elapsed,
                          **dict(stats, outcome='model_mismatch'))
        return None

    @property
    def restarts(self) -> int:
        """Workers replaced after they died or were killed."""
        return self._slot.restarts

    def close(self) -> None:
        with self._lock:
            self._slot.close()

    # -- the worker --------------------------------------------------------------------------

    def _ensure_worker(self) -> WorkerProcess:
        worker, fresh = self._slot.ensure(self._new_worker)
        if fresh:
            self._sent = None  # a new worker has seen no robot and scene yet
        return worker

    def _new_worker(self) -> WorkerProcess:
        argv, env = self.worker_command()
        return WorkerProcess(self.config.planning.worker_start_timeout_s, argv, env,
                             what=f'{self.label} worker')

    def _scene_key(self, task: Task) -> str:
        """What the worker must have loaded for ``task``: robot, objects, hidden objects."""
        return task.scene.objects_hash() + repr(task.scene.robot) + repr(
            self.config.hidden_object_ids)

    def models(self, task: Task) -> tuple[RobotModel, CollisionWorld]:
        """Our robot and collision model of ``task``'s scene (cached per scene)."""
        key = task.scene.objects_hash() + repr(task.scene.robot)
        if self._model is None or self._model[0] != key:
            robot = load_robot(task.scene.robot)
            self._model = (key, robot, CollisionWorld(robot, task.scene.shapes))
        return self._model[1], self._model[2]

    def exchange(self, request: dict, task: Task, robot: RobotModel, wait_s: float,
                 stats: dict) -> dict | PlanResult:
        """Send ``request`` (with the robot and scene if the worker lacks them) and wait
        ``wait_s`` for the answer, under the victim's lock. A dead worker is an
        ``INTERNAL_ERROR``, a silent one is killed (``TIMED_OUT``), an error it reports is an
        ``INTERNAL_ERROR``; else the answer."""
        nq = robot.nq
        key = self._scene_key(task)
        with self._lock:
            t_sent = time.monotonic()
            try:
                worker = self._ensure_worker()
                if self._sent != key:
                    request = dict(request, **self.setup_fields(task, robot))
                t_sent = time.monotonic()
                worker.send(request)
                answer = worker.read(t_sent + wait_s)
            except WorkerDied as exc:
                self._slot.kill()
                log.error('%s', exc)
                return failed(PlanStatus.INTERNAL_ERROR, str(exc), nq,
                              time.monotonic() - t_sent, worker_died=True, **stats)
            stats['round_trip_s'] = time.monotonic() - t_sent
            if answer is None:
                self._slot.kill()
                return failed(PlanStatus.TIMED_OUT, f'watchdog: {self.label} gave no answer '
                              f'within {wait_s:g} s; worker killed', nq, stats['round_trip_s'],
                              watchdog=True, **stats)
            if 'error' in answer:
                return failed(PlanStatus.INTERNAL_ERROR, f'{self.label} worker: '
                              f'{answer["error"]}', nq, stats['round_trip_s'], **stats)
            self._sent = key
            return answer

    def call(self, request: dict, task: Task, robot: RobotModel, budget: float, stats: dict):
        """The worker's answer to a request with a ``budget`` [s], or the ``PlanResult`` of a
        watchdog kill (after budget + ``watchdog_margin_s``), a dead worker or an error."""
        return self.exchange(request, task, robot,
                             budget + self.config.planning.watchdog_margin_s, stats)

    def preload(self, task: Task, robot: RobotModel, request: dict,
                wait_s: float) -> dict | PlanResult | None:
        """Send ``request`` with the robot and scene, waiting ``wait_s`` for the answer, unless
        the worker has them already (None): a victim whose loading is slow does it before a
        plan request's clock starts. A worker that cannot start is an ``INTERNAL_ERROR``."""
        with self._lock:
            try:
                self._ensure_worker()
            except WorkerDied as exc:
                self._slot.kill()
                return failed(PlanStatus.INTERNAL_ERROR, str(exc), robot.nq, worker_died=True)
            if self._sent == self._scene_key(task):
                return None
        return self.exchange(request, task, robot, wait_s, {})

    def kill_worker(self) -> None:
        """Kill the worker (one that answered nonsense); the next request starts another."""
        self._slot.kill()
