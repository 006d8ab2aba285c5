"""The victims: OMPL planners to goal regions in a watched worker process. No ROS.

Goal sampling and the start configuration live in ``advocc_ros.model.ik``; they are re-exported
here for the planners' users. The planners themselves (``solve``, ``Planner``,
``LocalPlanners``) are imported on first use: importing ``advocc_ros.planning.witness`` (which
the planner-free attack core does, for the witness's type and certificate) must not load OMPL
or the worker (issue 25).
"""

import importlib

from advocc_ros.model.ik import GoalSampler, start_configuration
from advocc_ros.planning.types import (PLANNERS, REQUEST_ERRORS, PlanResult, PlanStatus,
                                       PlanningConfig, planner_class_name, validate_request)

_LAZY = {'solve': 'advocc_ros.planning.solve', 'Planner': 'advocc_ros.planning.worker',
         'WorkerDied': 'advocc_ros.planning.worker', 'LocalPlanners': 'advocc_ros.planning.pool'}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


__all__ = [
    'GoalSampler', 'LocalPlanners', 'PLANNERS', 'REQUEST_ERRORS', 'PlanResult', 'PlanStatus',
    'Planner',
    'PlanningConfig', 'WorkerDied', 'planner_class_name', 'solve', 'start_configuration',
    'validate_request']
