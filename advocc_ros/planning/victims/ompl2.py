"""OMPL 2.0 planners as victims: AORRTC (``aorrtc``) and OMPL 2's RRTConnect (``rrtconnect2``).

OMPL 2.0.1 (PyPI ``ompl``, nanobind bindings) has AORRTC, but its module is also called
``ompl`` and its PRM* deadlocks with Python validity checkers (PRM's ``solve`` starts a second
C++ thread that calls the checker while the first holds the GIL: our three planners stay on
1.7.0). So these victims run our planning worker (``advocc_ros.planning.worker``, the same
``solve``: goal region by IK inside the budget, our exact validity and motion checks, MoveIt's
post-processing) in another interpreter, ``.venv-ompl2`` (``make install`` creates it), with
the same watchdog. Every path they return is re-checked here: from the start, into the goal
region, and collision-free in our model every ``VictimConfig.check_step_rad``.
"""

from __future__ import annotations

import hashlib
import os
import pathlib

import numpy as np

from advocc_ros.model.cache import user_cache_root
from advocc_ros.planning.types import PlanResult, PlanStatus, failed
from advocc_ros.planning.victims.base import Task, VictimConfig, first_collision_along
from advocc_ros.planning.victims.ompl import OmplVictim
from advocc_ros.planning.victims.outside import venv_python
from advocc_ros.planning.worker import Planner

PYTHON_ENV = 'ADVOCC_OMPL2_PYTHON'
PLANNERS = {'aorrtc': 'AORRTC', 'rrtconnect2': 'RRTConnect'}
"""Victim name -> OMPL 2 planner class."""


def ompl2_python(config: VictimConfig = VictimConfig()) -> pathlib.Path:
    """The OMPL 2 venv's interpreter (``VictimConfig.ompl2_python``, ``$ADVOCC_OMPL2_PYTHON``,
    the checkout's ``.venv-ompl2``)."""
    return venv_python(config.ompl2_python, PYTHON_ENV, '.venv-ompl2', 'OMPL 2 victims')


def source_path() -> pathlib.Path:
    """A folder whose only package is ours: the OMPL 2 interpreter's ``PYTHONPATH``. In a
    checkout it is the checkout; where our package sits in a site-packages (beside OMPL 1.7),
    a folder in the cache with a link to the package, so nothing else of our venv shadows the
    OMPL 2 venv's packages."""
    package = pathlib.Path(__file__).resolve().parents[2]
    if not any((package.parent / name).exists() for name in ('ompl', 'numpy', 'pinocchio')):
        return package.parent
    folder = user_cache_root() / 'ompl2' / hashlib.sha256(str(package).encode()).hexdigest()[:16]
    link = folder / package.name
    if not link.exists():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f'.{package.name}.{os.getpid()}'
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(package, target_is_directory=True)
        os.replace(tmp, link)
    return folder


def worker_command(python: pathlib.Path) -> tuple[list[str], dict]:
    """argv and environment of our planning worker in the OMPL 2 interpreter: our package on
    its path (:func:`source_path`), and none of our venv's library or Python paths (its OMPL
    1.7 must not load)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'PYTHONHOME', 'LD_LIBRARY_PATH', 'VIRTUAL_ENV')}
    env['PYTHONPATH'] = str(source_path())
    return [str(python), '-P', '-c', 'from advocc_ros.planning.worker import worker_main; '
            'worker_main()'], env


class Ompl2Victim(OmplVictim):
    """``Victim`` over an OMPL 2 planner in a watched worker of the OMPL 2 venv."""

    def __init__(self, name: str, config: VictimConfig = VictimConfig()):
        if name not in PLANNERS:
            raise ValueError(f'{name!r} is not an OMPL 2 victim; known: {sorted(PLANNERS)}')
        super().__init__(PLANNERS[name], config)
        self.name, self.planner_id = name, PLANNERS[name]
        self._python = ompl2_python(config)

    def new_planner(self, scene) -> Planner:
        """A ``Planner`` over our planning worker in the OMPL 2 interpreter."""
        return Planner(scene, self.config.planning, lambda: worker_command(self._python))

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        result = super().plan(task, time_budget_s, seed)
        result.stats['ompl'] = self.planner.ompl_version
        return self._recheck(task, result) if result.success else result

    def _recheck(self, task: Task, result: PlanResult) -> PlanResult:
        """``result`` unless its path misses the start or the goal region (an internal error:
        our worker checked both) or collides in our model between its waypoints (the planner's
        motion check stepped over an obstacle: an invalid path, as for ours)."""
        from advocc_ros.kinematics.ik import GoalSampler

        robot = self.planner.robot
        world = self.world_for(task, robot)
        path, step, nq = result.path, self.config.check_step_rad, robot.nq
        region = GoalSampler(robot, world.in_collision, task.goal, np.random.default_rng(0))
        if len(path) < 2 or not np.allclose(path[0], task.q_start, atol=1e-6) \
                or region.region_distance(path[-1]) > 0.0:
            return failed(PlanStatus.INTERNAL_ERROR, f'{self.planner_id} (OMPL 2): its path does '
                          'not run from the start into the goal region', nq,
                          result.planning_time_s, **result.stats)
        hit = first_collision_along(world, path, step)
        if hit >= 0:
            return failed(PlanStatus.INVALID_MOTION_PLAN, f'{self.planner_id} (OMPL 2): its path '
                          f'collides in our model at state {hit} (checked every {step:g} rad)',
                          nq, result.planning_time_s, **result.stats)
        return result


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> Ompl2Victim:
    """The registry's factory (``make_victim('aorrtc')``, ``make_victim('rrtconnect2')``)."""
    return Ompl2Victim(name, config)
