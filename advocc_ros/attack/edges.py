"""The edges of an attack: the one step around the planner-free core that may start a planner.

``advocc_ros.attack.api.attack`` queries no planner. What needs one, the task's *witness* (a
collision-free path from the start into the goal region on the unattacked scene), is found here,
once per task, by the tool and never by the victim, and reported apart from the attack's time:

1. the request is checked first (``attack.request.validate_request``, the task check of
   ``model.task_check`` included): a refused task starts nothing;
2. the witness, when the ``solvable`` policy needs it or ``AttackConfig.search_witness`` asks for
   a verdict that can say ``certified``: ``planning.witness_cache.find_witnesses``, one search in a
   fresh planning worker for the task's candidate witnesses, cached per task in the process and
   on disk; its wall time is ``stats['witness_search_ms']``, never part of ``compute_s``;
3. the core attack, with the candidates as data (under ``solvable`` it keeps one of them:
   ``attack.policy.choose_witness``).

``attack_task`` is what ``advocc attack``, ``advocc export``, the data set builder and the
heatmap server's ``~/attack`` call; ``advocc perf attack`` and the audit call
:func:`task_witness` once per task.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from advocc_ros.attack.api import attack
from advocc_ros.attack.request import box_size, validate_request
from advocc_ros.attack.types import (DEFAULT_METHOD, AttackConfig, AttackError, AttackResult,
                                     AttackStatus)
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError


@dataclasses.dataclass(frozen=True)
class WitnessSearch:
    """The task's candidate witnesses and what finding them cost."""

    witnesses: tuple
    """``planning.witness.Witness`` candidates; empty when the search found no path (or
    failed)."""
    search_s: float
    """Wall time of the search [s] (a cached witness: the cache lookup)."""


def task_witness(robot: RobotModel, objects, q_init, goal: GoalRegion,
                 clearance_m: float = 0.0) -> WitnessSearch:
    """The candidate witnesses of the task (module docstring), planned ``clearance_m`` (the
    victim margin) clear of the scene when they can be; starts a planning worker unless they
    are cached."""
    from advocc_ros.planning.witness import WITNESS_TIME_S
    from advocc_ros.planning.witness_cache import find_witnesses

    t0 = time.perf_counter()
    witnesses = find_witnesses(robot, tuple(objects), np.asarray(q_init, dtype=float), goal,
                               WITNESS_TIME_S, clearance_m)
    return WitnessSearch(witnesses, time.perf_counter() - t0)


def needs_witness(cfg: AttackConfig, goal_policy: str | None, certify: bool = True) -> bool:
    """Whether an attack under ``goal_policy`` (None: ``cfg``'s) gets a witness search."""
    return (goal_policy or cfg.goal_policy) == 'solvable' or (certify and cfg.search_witness)


def attack_task(heatmap, robot: RobotModel, objects, q_init, goal: GoalRegion, budget: int,
                method: str = DEFAULT_METHOD, cfg: AttackConfig = AttackConfig(),
                certify: bool = True, **options) -> AttackResult:
    """The request checked, the witness found if needed, then ``attack`` (same arguments;
    ``options``: its keyword arguments but ``witness``). Never raises for a bad request."""
    policy = options.get('goal_policy') or cfg.goal_policy
    if not needs_witness(cfg, policy, certify):
        return attack(heatmap, robot, objects, q_init, goal, budget, method, cfg,
                      certify=certify, **options)
    try:
        validate_request(heatmap, robot, tuple(objects), q_init, goal, budget, method,
                         box_size(cfg, options.get('box_size_m')), cfg, policy)
    except (AttackError, SceneError, RobotError):  # the core answers it; nothing was started
        return attack(heatmap, robot, objects, q_init, goal, budget, method, cfg,
                      certify=False, **options)
    search = task_witness(robot, objects, q_init, goal, cfg.victim_margin_m)
    result = attack(heatmap, robot, objects, q_init, goal, budget, method, cfg,
                    certify=certify, witness=search.witnesses, **options)
    stats = dict(result.stats, witness_search_ms=round(search.search_s * 1e3, 3))
    if result.status == AttackStatus.NO_WITNESS:
        return dataclasses.replace(result, stats=stats,
                                   message=no_witness_message(goal.form))
    return dataclasses.replace(result, stats=stats)


def no_witness_message(goal_form: str = 'region') -> str:
    """Why a ``solvable`` attack was refused after the witness search found nothing, naming
    the goal as its form poses it (a region, or one joint configuration)."""
    from advocc_ros.planning.witness import WITNESS_TIME_S

    target = 'to the goal configuration' if goal_form == 'joint' else 'into the goal region'
    return (f'no witness: RRTConnect found no path {target} on the unattacked scene '
            f'within {WITNESS_TIME_S:g} s, or every path found grazed an object closer than the '
            'certificate\'s floor (or the search failed), so no attack can be certified to keep '
            'a solution')


__all__ = ['WitnessSearch', 'attack_task', 'needs_witness', 'no_witness_message',
           'task_witness']
