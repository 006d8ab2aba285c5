"""MPlib (ManiSkill's planner: its own OMPL 1.6 RRTConnect, FCL on the robot's meshes) as a victim.

MPlib 0.2.1 needs numpy < 2, so it runs in its own venv (``.venv-mplib``, made by ``make
install``) and its own process: ``mplib_worker.py``, spoken to in JSON lines through our
worker's pipes (``advocc_ros.planning.worker.WorkerProcess``). The parent keeps what MPlib does not
have: the goal region becomes K goal configurations (``Task.goal_list``, our sampler with the
boxes, before the clock), re-checked by the worker in MPlib's model; the start is
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
import os
import pathlib
import re

import numpy as np

from advocc_ros.fileio import atomic_write_text
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, example_robot_data_share, resolve_path
from advocc_ros.model.cache import user_cache_root
from advocc_ros.planning.types import PlanResult, PlanStatus, failed
from advocc_ros.planning.victims.base import Task, VictimConfig, path_length_rad
from advocc_ros.planning.victims.outside import OutsideVictim, venv_python
from advocc_ros.planning.worker import WorkerDied

PYTHON_ENV = 'ADVOCC_MPLIB_PYTHON'
WORKER_SCRIPT = pathlib.Path(__file__).with_name('mplib_worker.py')


def mplib_python(config: VictimConfig = VictimConfig()) -> pathlib.Path:
    """The MPlib venv's interpreter (``VictimConfig.mplib_python``, ``$ADVOCC_MPLIB_PYTHON``,
    the checkout's ``.venv-mplib``)."""
    return venv_python(config.mplib_python, PYTHON_ENV, '.venv-mplib', 'MPlib victim')


def _cache_dir() -> pathlib.Path:
    return user_cache_root() / 'mplib'


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


class MplibVictim(OutsideVictim):
    """``Victim`` over MPlib's RRTConnect in a watched worker of the MPlib venv."""

    label = 'MPlib'

    def __init__(self, name: str = 'mplib', config: VictimConfig = VictimConfig()):
        super().__init__(name, config)
        self._python = mplib_python(config)

    def worker_command(self) -> tuple[list[str], dict]:
        env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'PYTHONHOME')}
        return [str(self._python), '-P', str(WORKER_SCRIPT)], env

    def setup_fields(self, task: Task, robot: RobotModel) -> dict:
        return {'robot': {'urdf': str(mplib_urdf(robot)),
                          'srdf': str(resolve_path(robot.spec.srdf).resolve()),
                          'move_group': robot.spec.ee_link, 'joints': list(robot.joint_names),
                          'locked': robot.locked_values},
                'objects': objects_data(task, self.config.hidden_object_ids)}

    def plan_result(self, answer: dict, robot: RobotModel, world: CollisionWorld,
                    q_start: np.ndarray, goals: np.ndarray, budget: float, stats: dict
                    ) -> PlanResult:
        """The worker's answer as a ``PlanResult``, the path re-validated in both models."""
        nq = robot.nq
        if answer['status'] == 'start_invalid':
            return failed(PlanStatus.START_STATE_IN_COLLISION, 'the start state is free in our '
                          'model but in collision in MPlib\'s', nq, 0.0, **stats)
        stats['goal_configs_valid_victim'] = int(sum(answer['goals_valid']))
        if answer['status'] == 'no_valid_goal':
            return failed(PlanStatus.GOAL_STATE_INVALID, f'none of the {len(goals)} goal '
                          'configurations is collision-free in MPlib\'s model', nq, 0.0, **stats)
        solve_s, ompl = float(answer['solve_s']), str(answer['ompl_status'])
        stats['ompl_status'] = ompl
        if ompl != 'Exact solution':
            status = PlanStatus.TIMED_OUT if ompl in ('Approximate solution', 'Timeout') \
                else PlanStatus.PLANNING_FAILED
            return failed(status, f'MPlib RRTConnect: {ompl} within {budget:g} s', nq, solve_s,
                          **stats)
        path = np.asarray(answer['path'], float).reshape(-1, nq)
        stats.update(first_solution_s=solve_s, path_length_rad=path_length_rad(path))
        failure = self.checked_path(path, world, q_start, goals, solve_s, stats,
                                    int(answer['first_collision']))
        if failure is not None:
            return failure
        return PlanResult(PlanStatus.SUCCESS, f'MPlib RRTConnect: solved in {solve_s:.3f} s',
                          path, solve_s, stats)

    def check(self, task: Task, Q: np.ndarray) -> np.ndarray:
        """MPlib's own collision verdicts for configurations ``Q`` (N, nq) in ``task``'s scene."""
        robot, _ = self.models(task)
        answer = self.call({'op': 'check', 'q': np.asarray(Q, float).tolist()}, task, robot,
                           10.0, {})
        if isinstance(answer, PlanResult):
            raise WorkerDied(answer.message)
        return np.array(answer['collides'], bool)


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> MplibVictim:
    """The registry's factory (``advocc_ros.planning.victims.make_victim('mplib')``)."""
    return MplibVictim(name, config)
