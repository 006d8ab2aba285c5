"""MPlib (ManiSkill's planner: its own OMPL 1.6 RRTConnect, FCL on the robot's meshes) as a victim.

MPlib 0.2.1 needs numpy < 2, so it runs in its own venv (``.venv-mplib``, made by ``make
install``) and its own process: ``mplib_worker.py``, spoken to in JSON lines through our
worker's pipes (``advocc_ros.planning.worker._Worker``). The parent keeps what MPlib does not
have: the goal region becomes K goal configurations (:func:`goal_configurations`, our sampler
with the boxes, outside the budget), re-checked by the worker in MPlib's model; the start is
checked in both models (MPlib itself only warns); every exact solution is re-validated at
``check_step_rad`` in MPlib's model (``INVALID_MOTION_PLAN`` if its coarse motion check
stepped over an obstacle) and in ours (``MODEL_MISMATCH`` if it is free on the meshes but
not on our hulls). A worker that does not answer within budget + margin is killed (the trial
is ``TIMED_OUT``, as for our planners); one that dies is an ``INTERNAL_ERROR``.

MPlib plans with ``range=0.0`` (OMPL's default step), ``simplify=False`` (it then returns at its
first solution, so the time to first solution is its solve time) and ``set_global_seed``.
MPlib resolves mesh paths relative to the URDF's folder and knows no ``package://``: the URDF
is copied into a cache directory with relative mesh paths.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pathlib
import re
import threading
import time

import numpy as np

from advocc_ros.fileio import atomic_write_text
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, example_robot_data_share, load_robot, \
    resolve_path
from advocc_ros.planning.types import PlanResult, PlanStatus, _fail, validate_request
from advocc_ros.planning.victims import Task, VictimConfig, first_collision_along, \
    path_length_rad
from advocc_ros.planning.worker import WorkerDied, _Worker

log = logging.getLogger(__name__)

PYTHON_ENV = 'ADVOCC_MPLIB_PYTHON'
WORKER_SCRIPT = pathlib.Path(__file__).with_name('mplib_worker.py')
_CHECKOUT = pathlib.Path(__file__).resolve().parents[3]


class VictimUnavailable(ValueError):
    """The victim's interpreter or library is not installed."""


def mplib_python(config: VictimConfig = VictimConfig()) -> pathlib.Path:
    """The MPlib venv's interpreter (``VictimConfig.mplib_python``, ``$ADVOCC_MPLIB_PYTHON``,
    the checkout's ``.venv-mplib``), or ``VictimUnavailable`` saying how to make it."""
    path = pathlib.Path(config.mplib_python or os.environ.get(PYTHON_ENV)
                        or _CHECKOUT / '.venv-mplib' / 'bin' / 'python')
    if not path.is_file():
        raise VictimUnavailable(f'MPlib victim: no interpreter at {path}; run `make install` '
                                f'(it creates .venv-mplib) or set {PYTHON_ENV}')
    return path


def _cache_dir() -> pathlib.Path:
    base = os.environ.get('XDG_CACHE_HOME') or pathlib.Path.home() / '.cache'
    return pathlib.Path(base) / 'advocc_ros' / 'mplib'


def mplib_urdf(robot: RobotModel, cache_dir: pathlib.Path | None = None) -> pathlib.Path:
    """A copy of the robot's URDF whose mesh paths are relative to the copy's folder."""
    urdf = resolve_path(robot.spec.urdf).resolve()
    text = urdf.read_text()
    folder = (cache_dir or _cache_dir()) / hashlib.sha256(
        (str(urdf) + text).encode()).hexdigest()[:16]
    folder.mkdir(parents=True, exist_ok=True)

    def relative(match: re.Match) -> str:
        name = match.group(2)
        if name.startswith('package://'):
            target = example_robot_data_share() / name[len('package://'):]
        else:
            target = urdf.parent / name.removeprefix('file://')
        return f'{match.group(1)}{os.path.relpath(target.resolve(), folder)}{match.group(3)}'

    copy = folder / urdf.name
    atomic_write_text(copy, re.sub(r'(<mesh\s[^>]*filename=")([^"]+)(")', relative, text))
    return copy


def objects_data(task: Task, hidden: tuple[str, ...] = ()) -> list[dict]:
    """The scene's shapes as the worker reads them (position, quaternion xyzw, dims, points)."""
    out = []
    for obj in task.scene.objects:
        if obj.id in hidden:
            continue
        for shape in obj.shapes:
            entry = {'id': obj.id, 'kind': shape.kind, 'dims': list(shape.dims),
                     'position': list(shape.pose.position_m),
                     'quaternion': list(shape.pose.quat_xyzw)}
            if shape.kind in ('mesh', 'cloud'):
                entry['vertices'] = np.asarray(shape.vertices, float).tolist()
            if shape.kind == 'mesh':
                entry['faces'] = np.asarray(shape.faces, int).tolist()
            out.append(entry)
    return out


class MplibVictim:
    """``Victim`` over MPlib's RRTConnect in a watched worker of the MPlib venv."""

    def __init__(self, name: str = 'mplib', config: VictimConfig = VictimConfig()):
        self.name, self.config = name, config
        self._python = mplib_python(config)
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self._sent: dict[str, str] = {}
        self._model: tuple[str, RobotModel, CollisionWorld] | None = None

    def start(self, scene=None) -> 'MplibVictim':
        with self._lock:
            self._ensure_worker()
        return self

    def _ensure_worker(self) -> _Worker:
        if self._worker is None or self._worker.proc.poll() is not None:
            if self._worker is not None:
                self._worker.kill()
            env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'PYTHONHOME')}
            self._worker = _Worker(self.config.planning.worker_start_timeout_s,
                                   [str(self._python), '-P', str(WORKER_SCRIPT)], env,
                                   what='MPlib worker')
            self._sent = {}
        return self._worker

    def _kill_worker(self) -> None:
        if self._worker is not None:
            self._worker.kill()
            self._worker = None

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
        goals = task.goals(robot, world, self.config.goal_configs, seed)
        stats = {'victim': self.name, 'goal_sampling_s': time.monotonic() - t0,
                 'goal_configs': len(goals)}
        if not len(goals):
            return _fail(PlanStatus.GOAL_IN_COLLISION, 'our goal sampler found no collision-free '
                         'goal configuration to hand to MPlib', nq, 0.0, **stats)
        request = {'op': 'plan', 'q_start': q_start.tolist(), 'goals': goals.tolist(),
                   'time_s': float(time_budget_s), 'seed': int(seed),
                   'check_step_rad': self.config.check_step_rad}
        answer = self._call(request, task, robot, time_budget_s, stats)
        if isinstance(answer, PlanResult):
            return answer
        return self._result(answer, robot, world, q_start, goals, time_budget_s, stats)

    def _call(self, request: dict, task: Task, robot: RobotModel, budget: float, stats: dict):
        """The worker's answer, or the ``PlanResult`` of a watchdog kill or a dead worker."""
        nq = robot.nq
        scene_key = task.scene.objects_hash() + repr(self.config.hidden_object_ids)
        with self._lock:
            try:
                worker = self._ensure_worker()
                if self._sent.get('robot') != robot.hash:
                    request['robot'] = {
                        'urdf': str(mplib_urdf(robot)),
                        'srdf': str(resolve_path(robot.spec.srdf).resolve()),
                        'move_group': robot.spec.ee_link, 'joints': list(robot.joint_names),
                        'locked': robot.locked_values}
                    self._sent = {}
                if self._sent.get('scene') != scene_key:
                    request['objects'] = objects_data(task, self.config.hidden_object_ids)
                t_sent = time.monotonic()
                worker.send(request)
                answer = worker.read(t_sent + budget + self.config.planning.watchdog_margin_s)
            except WorkerDied as exc:
                self._kill_worker()
                log.error('%s', exc)
                return _fail(PlanStatus.INTERNAL_ERROR, str(exc), nq, 0.0, worker_died=True,
                             **stats)
            stats['round_trip_s'] = time.monotonic() - t_sent
            if answer is None:
                self._kill_worker()
                return _fail(PlanStatus.TIMED_OUT, f'watchdog: MPlib gave no answer within '
                             f'{budget:g} s + {self.config.planning.watchdog_margin_s:g} s; '
                             'worker killed', nq, stats['round_trip_s'], watchdog=True, **stats)
            if 'error' in answer:
                return _fail(PlanStatus.INTERNAL_ERROR, f'MPlib worker: {answer["error"]}', nq,
                             0.0, **stats)
            self._sent = {'robot': robot.hash, 'scene': scene_key}
            return answer

    def _result(self, answer: dict, robot: RobotModel, world: CollisionWorld,
                q_start: np.ndarray, goals: np.ndarray, budget: float, stats: dict
                ) -> PlanResult:
        """The worker's answer as a ``PlanResult``, the path re-validated in both models."""
        nq = robot.nq
        if answer['status'] == 'start_invalid':
            return _fail(PlanStatus.START_STATE_IN_COLLISION, 'the start state is free in our '
                         'model but in collision in MPlib\'s', nq, 0.0, **stats)
        stats['goal_configs_valid_victim'] = int(sum(answer['goals_valid']))
        if answer['status'] == 'no_valid_goal':
            return _fail(PlanStatus.GOAL_STATE_INVALID, f'none of the {len(goals)} goal '
                         'configurations is collision-free in MPlib\'s model', nq, 0.0, **stats)
        solve_s, ompl = float(answer['solve_s']), str(answer['ompl_status'])
        stats['ompl_status'] = ompl
        if ompl != 'Exact solution':
            status = PlanStatus.TIMED_OUT if ompl in ('Approximate solution', 'Timeout') \
                else PlanStatus.PLANNING_FAILED
            return _fail(status, f'MPlib RRTConnect: {ompl} within {budget:g} s', nq, solve_s,
                         **stats)
        path = np.asarray(answer['path'], float).reshape(-1, nq)
        if len(path) < 2 or not np.allclose(path[0], q_start, atol=1e-6) or not np.any(
                np.all(np.isclose(goals, path[-1], atol=1e-6), axis=1)):
            return _fail(PlanStatus.INTERNAL_ERROR, 'MPlib\'s path does not run from the start '
                         'to a goal configuration', nq, solve_s, **stats)
        stats.update(first_solution_s=solve_s, path_length_rad=path_length_rad(path))
        step = self.config.check_step_rad
        if answer['first_collision'] >= 0:
            return _fail(PlanStatus.INVALID_MOTION_PLAN, f'MPlib: its solution collides in its '
                         f'own model at state {answer["first_collision"]} (checked every '
                         f'{step:g} rad): its motion check stepped over an obstacle', nq,
                         solve_s, **stats)
        ours = first_collision_along(world, path, step)
        if ours >= 0:
            return _fail(PlanStatus.MODEL_MISMATCH, f'MPlib: its solution is free on its meshes '
                         f'but collides in our model (convex hulls) at state {ours} (checked '
                         f'every {step:g} rad)', nq, solve_s, **stats)
        return PlanResult(PlanStatus.SUCCESS, f'MPlib RRTConnect: solved in {solve_s:.3f} s',
                          path, solve_s, stats)

    def check(self, task: Task, Q: np.ndarray) -> np.ndarray:
        """MPlib's own collision verdicts for configurations ``Q`` (N, nq) in ``task``'s scene."""
        robot, _ = self._models(task)
        answer = self._call({'op': 'check', 'q': np.asarray(Q, float).tolist()}, task, robot,
                            10.0, {})
        if isinstance(answer, PlanResult):
            raise WorkerDied(answer.message)
        return np.array(answer['collides'], bool)

    def close(self) -> None:
        with self._lock:
            if self._worker is not None:
                self._worker.close()
                self._worker = None

    def __del__(self):
        worker = getattr(self, '_worker', None)
        if worker is not None:
            worker.kill()


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> MplibVictim:
    """The registry's factory (``advocc_ros.planning.victims.make_victim('mplib')``)."""
    return MplibVictim(name, config)
