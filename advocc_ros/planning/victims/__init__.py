"""Victims: planners the attack is measured on, ours and others', behind one small protocol.

A victim plans a :class:`Task` (scene with the boxes, start, goal region) under a budget and a
seed and answers a ``PlanResult``: a ``PlanStatus`` (the failure modes of
``advocc_ros.evaluation.outcomes``), the path (N, nq) in our joint order, the planning time,
and ``stats['first_solution_s']`` plus victim-specific detail. Names:

- our OMPL 1.7 planners (``rrtconnect``, ``prmstar``, ``bkpiece1``, any OMPL geometric planner
  id): :class:`advocc_ros.planning.victims.ompl.OmplVictim`; they sample the goal region
  themselves, or take the goal list (``VictimConfig.ompl_goal_list``);
- ``aorrtc``, ``rrtconnect2``: OMPL 2.0.1's AORRTC and RRTConnect, our planning worker in the
  OMPL 2 venv (:mod:`advocc_ros.planning.victims.ompl2`);
- ``mplib``: MPlib 0.2.1's RRTConnect on FCL and the robot's meshes, in its own interpreter;
- ``trajopt``: Tesseract 0.5.1's TrajOpt (sequential convex optimization), in a worker;
- outside victims registered by module (imported lazily by name, so a missing optional
  dependency only fails when that victim is asked for).

Victims that take only configurations get the trial's goal list
(:meth:`Task.goal_list`, ``advocc_ros.planning.goal_list``): the same seeded K goal
configurations of the region for every victim (our goal sampler, with the boxes, before the
clock, with a generous budget), re-checked in the victim's own model. Every path an outside
victim returns is re-validated by our checker (:func:`first_collision_along`, at
``VictimConfig.check_step_rad``) and by its own.
"""

from __future__ import annotations

import importlib

from advocc_ros.planning.types import planner_class_name
from advocc_ros.planning.victims.base import (Task, Victim, VictimConfig, densify,
                                              first_collision_along, goal_configurations,
                                              path_length_rad)

_OUTSIDE: dict[str, str] = {
    'aorrtc': 'advocc_ros.planning.victims.ompl2',
    'rrtconnect2': 'advocc_ros.planning.victims.ompl2',
    'mplib': 'advocc_ros.planning.victims.mplib',
    'trajopt': 'advocc_ros.planning.victims.trajopt_victim',
}
"""Outside victims: name -> module defining ``make_victim(name, config) -> Victim``."""
OUTSIDE_LABELS = {'aorrtc': 'AORRTC', 'rrtconnect2': 'RRT (OMPL 2)', 'mplib': 'MPlib',
                  'trajopt': 'TrajOpt'}
"""How tables and reports name the outside victims."""


def register(name: str, module: str) -> None:
    """Register an outside victim ``name`` served by ``module`` (imported when first used)."""
    _OUTSIDE[name.strip().lower()] = module


def victim_names() -> list[str]:
    """The outside victims' names (our OMPL planners are named by their OMPL ids)."""
    return sorted(_OUTSIDE)


def is_victim(name: str) -> bool:
    """Whether ``name`` is an OMPL planner id or a registered outside victim."""
    return planner_class_name(name) is not None or name.strip().lower() in _OUTSIDE


def is_outside(name: str) -> bool:
    """Whether ``name`` is a registered victim that is not one of our OMPL 1.7 planners (a
    registered name wins over an OMPL id: ``aorrtc`` is OMPL 2's, in its own venv)."""
    return name.strip().lower() in _OUTSIDE


def make_victim(name: str, config: VictimConfig = VictimConfig()) -> Victim:
    """The victim called ``name``; ``ValueError`` naming the known ones if there is none."""
    key = name.strip().lower()
    if key not in _OUTSIDE and planner_class_name(name) is not None:
        from advocc_ros.planning.victims.ompl import OmplVictim
        return OmplVictim(name, config)
    if key not in _OUTSIDE:
        raise ValueError(f'unknown planner {name!r}; known: OMPL planner ids (rrtconnect, '
                         f'prmstar, bkpiece1, ...) and {victim_names()}')
    return importlib.import_module(_OUTSIDE[key]).make_victim(key, config)


__all__ = ['OUTSIDE_LABELS', 'Task', 'Victim', 'VictimConfig', 'densify', 'first_collision_along',
           'goal_configurations', 'is_outside', 'is_victim', 'make_victim', 'path_length_rad',
           'register', 'victim_names']
