"""The TrajOpt victim (``trajopt``) in a watched worker process (see ``trajopt`` for the solver).

TrajOpt's SQP runs in C++ and cannot be stopped from Python (the bindings' low-level
``OptimizeProblem``, which would take a time limit, does not accept the problem its own
``ConstructProblem`` returns), so the victim plans in a long-lived child process of this
interpreter (``tesseract-robotics`` imports with our numpy 2): ``OutsideVictim`` starts and
watches it, samples the goal list and kills a worker that overruns budget + margin (an attempt
started before the deadline may end after it). The robot and scene are loaded by a request of
their own, outside the budget and the watchdog's deadline. The worker re-checks the goal list in
Tesseract's model, restarts TrajOpt until an attempt passes both dense checks or the budget
ends, and answers a ``PlanResult``; the parent re-validates the path once more in our model.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pathlib
import signal
import sys

import numpy as np

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import RobotModel, load_robot
from advocc_ros.planning.types import PlanResult, PlanStatus, failed
from advocc_ros.planning.victims.base import Task, VictimConfig
from advocc_ros.planning.victims.outside import OutsideVictim

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
                config = TrajOptConfig(**req['trajopt'])
                step = float(req['check_step_rad'])
                if solver is None or solver.robot.hash != robot.hash \
                        or solver.config != config or solver.check_step_rad != step:
                    solver = TrajOptSolver(robot, config, step)
                solver.set_objects(scene.shapes)
            if req.get('op') == 'load':
                out.write(json.dumps({'loaded': solver.robot.hash}) + '\n')
                continue
            if solver is None:
                raise ValueError('worker has no scene for this request')
            result = solver.plan(np.asarray(req['q_start'], float),
                                 np.asarray(req['goals'], float), float(req['time_s']),
                                 int(req['seed']))
            out.write(json.dumps(result.to_data()) + '\n')
        except Exception as exc:  # a bad request or a bug must not kill the worker
            log.exception('request failed')
            out.write(json.dumps({'error': repr(exc)}) + '\n')


class TrajOptVictim(OutsideVictim):
    """``Victim`` over TrajOpt (Tesseract) in a watched worker process."""

    label = 'TrajOpt'

    def __init__(self, name: str = 'trajopt', config: VictimConfig = VictimConfig(),
                 trajopt=None):
        from advocc_ros.planning.victims.trajopt import TrajOptConfig

        super().__init__(name, config)
        self.trajopt = trajopt or TrajOptConfig()
        """``TrajOptConfig`` of the solver."""

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        error = self._load(task)
        return error if error is not None else super().plan(task, time_budget_s, seed)

    def _load(self, task: Task) -> PlanResult | None:
        """Have the worker load the robot and scene before the budget's clock starts.

        Loading the Tesseract robot takes ~1 s (3 s on a loaded machine); inside a plan
        request it would count against the watchdog, and a worker killed by the watchdog would
        pay it again on the next request and be killed again. None, or the error result.
        """
        robot, _ = self.models(task)
        answer = self.preload(task, robot, {'op': 'load',
                                            'check_step_rad': self.config.check_step_rad},
                              self.config.planning.worker_start_timeout_s)
        if answer is None or isinstance(answer, PlanResult):
            return answer
        if 'loaded' not in answer:
            self.kill_worker()
            return failed(PlanStatus.INTERNAL_ERROR, f'TrajOpt worker could not load the '
                          f'scene: {answer}', robot.nq)
        return None

    def worker_command(self) -> tuple[list[str], dict]:
        src = str(pathlib.Path(__file__).resolve().parents[3])
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(p for p in (src, env.get('PYTHONPATH')) if p)
        return [sys.executable, '-P', '-c', 'from advocc_ros.planning.victims.trajopt_victim '
                'import _worker_main; _worker_main()'], env

    def setup_fields(self, task: Task, robot: RobotModel) -> dict:
        scene = task.scene
        if self.config.hidden_object_ids:
            scene = dataclasses.replace(scene, objects=tuple(
                o for o in scene.objects if o.id not in self.config.hidden_object_ids))
        return {'scene': scene.to_data(), 'trajopt': dataclasses.asdict(self.trajopt)}

    def plan_result(self, answer: dict, robot: RobotModel, world: CollisionWorld,
                    q_start: np.ndarray, goals: np.ndarray, budget: float, stats: dict
                    ) -> PlanResult:
        """The worker's ``PlanResult``; a success's path re-validated here in our model."""
        result = PlanResult.from_data(answer, robot.nq)
        result.stats.update(stats)
        if 'goal_configs_valid' in result.stats:
            result.stats['goal_configs_valid_victim'] = result.stats['goal_configs_valid']
        if not result.success:
            return result
        failure = self.checked_path(result.path, world, q_start, goals,
                                    result.planning_time_s, result.stats)
        return result if failure is None else failure


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> TrajOptVictim:
    """The registry's factory (``advocc_ros.planning.victims.make_victim('trajopt')``)."""
    return TrajOptVictim(name, config)
