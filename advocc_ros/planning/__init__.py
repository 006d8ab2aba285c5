"""The victims: OMPL planners to goal regions in a watched worker process. No ROS.

Goal sampling and the start configuration live in ``advocc_ros.model.ik``; they are re-exported
here for the planners' users.
"""

from advocc_ros.model.ik import GoalSampler, start_configuration
from advocc_ros.planning.types import (PLANNERS, REQUEST_ERRORS, PlanResult, PlanStatus,
                                       PlanningConfig, planner_class_name, validate_request)
from advocc_ros.planning.solve import solve
from advocc_ros.planning.worker import Planner, WorkerDied
from advocc_ros.planning.pool import LocalPlanners

__all__ = [
    'GoalSampler', 'LocalPlanners', 'PLANNERS', 'REQUEST_ERRORS', 'PlanResult', 'PlanStatus',
    'Planner',
    'PlanningConfig', 'WorkerDied', 'planner_class_name', 'solve', 'start_configuration',
    'validate_request']
