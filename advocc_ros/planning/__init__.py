"""The victims: OMPL planners to goal regions in a watched worker process."""

from advocc_ros.planning.worker import (GoalSampler, Planner, planner_class_name, PLANNERS,
                                        PlanningConfig, PlanResult, PlanStatus, solve,
                                        start_configuration, validate_request, WorkerDied)

__all__ = [
    'GoalSampler', 'Planner', 'planner_class_name', 'PLANNERS', 'PlanningConfig', 'PlanResult',
    'PlanStatus', 'solve', 'start_configuration', 'validate_request', 'WorkerDied']
