"""The edges of an attack: the one step around the planner-free core that may start a planner.

``advocc_ros.attack.api.attack`` queries no planner. What needs one, the task's *witness* (a
collision-free path from the start into the goal region on the unattacked scene), is found here,
once per task, by the tool and never by the victim, and reported apart from the attack's time:

1. the request is checked first (``validate_request``, the task check of ``model.task_check``
   included): a refused task starts nothing;
2. the witness, when the ``solvable`` policy needs it or ``AttackConfig.search_witness`` asks for
   a verdict that can say ``certified``: ``planning.witness.find_witness``, one seeded
   RRTConnect run in a fresh planning worker, cached per task in the process and on disk; its
   wall time is ``stats['witness_search_ms']``, never part of ``compute_s``; for ``task``
   under ``solvable`` also the witnesses of ``TaskOptions.witness_seeds - 1`` more searches
   on seeds of their own (``planning.witness.find_witnesses``) and witnesses to
   ``TaskOptions.witness_ends`` goal configurations the planners rarely sample
   (``planning.end_witnesses``, one worker, cached alike), one of which the attack may keep
   (``attack.witness_choice``); and the goal sets that judge the task attack's candidates
   (``judge_goal_sets``: IK in worker processes, cached, timed as ``judge_goals_ms``);
3. the core attack, with the witnesses as data (it finds the goal sets cached).

``attack_task`` is what ``advocc attack``, ``advocc export`` and the heatmap server's
``~/attack`` call. ``advocc perf attack`` calls :func:`task_witness` once, before its timings,
and the audit once per task (the witness its attack keeps serves every prefix's verdict).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from advocc_ros.attack.api import attack, box_size, validate_request
from advocc_ros.attack.types import (DEFAULT_METHOD, AttackConfig, AttackError, AttackResult,
                                     AttackStatus)
from advocc_ros.model.robot import RobotError, RobotModel
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError


@dataclasses.dataclass(frozen=True)
class WitnessSearch:
    """The task's witnesses, the witnesses to rare goal configurations, and what finding them
    cost."""

    witness: Any
    """``planning.witness.Witness``, or None when the search found no path (or failed)."""
    search_s: float
    """Wall time of the searches [s] (cached witnesses: the cache lookups)."""
    goals_s: float = 0.0
    """Wall time of ``judge_goal_sets`` [s] (cached sets: the lookups)."""
    ends: tuple = ()
    """Witnesses to the goal configurations planners rarely sample (``planning.end_witnesses``):
    the ``task`` attack under ``solvable`` may keep one of them instead."""
    others: tuple = ()
    """Distinct witnesses of further searches on seeds of their own
    (``planning.witness.find_witnesses``), kept alike."""

    @property
    def candidates(self) -> tuple | None:
        """What ``attack(witness=...)`` takes: the task's witness first, then the other
        searches' witnesses, then the ends."""
        return None if self.witness is None else (self.witness, *self.others, *self.ends)


def task_witness(robot: RobotModel, objects, q_init, goal: GoalRegion,
                 ends: int = 0, seeds: int = 1, judge_samples: int = 0) -> WitnessSearch:
    """The witness of the task (see the module docstring) and, when it has one, those of
    ``seeds - 1`` more searches and witnesses to its ``ends`` rarest goal configurations
    (``attack.goals.rare_goal_configurations``), and ``judge_goal_sets``; starts planning
    and IK workers unless what they find is cached."""
    from advocc_ros.attack.goals import rare_goal_configurations
    from advocc_ros.planning.end_witnesses import find_end_witnesses
    from advocc_ros.planning.witness import find_witnesses

    t0 = time.perf_counter()
    objects, q_init = tuple(objects), np.asarray(q_init, dtype=float)
    witness, *others = find_witnesses(robot, objects, q_init, goal, max(seeds, 1)) or (None,)
    if witness is None:
        return WitnessSearch(None, time.perf_counter() - t0)
    goals_s = judge_goal_sets(robot, objects, goal, judge_samples, ends)
    found = ()
    if ends > 0:
        found = find_end_witnesses(robot, objects, q_init, goal,
                                   rare_goal_configurations(robot, objects, goal, ends))
    return WitnessSearch(witness, time.perf_counter() - t0 - goals_s, goals_s, found,
                         tuple(others))


def judge_goal_sets(robot: RobotModel, objects, goal: GoalRegion, judge_samples: int,
                    ends: int) -> float:
    """Sample (or read) the goal sets a ``task`` attack under ``solvable`` judges with (the
    ``judge_samples`` selection set; the rare-end set when ``ends``) in IK worker processes,
    so the core finds them cached; the wall time [s]."""
    from advocc_ros.attack.goals import rare_goal_configurations, selection_goal_samples
    from advocc_ros.kinematics.goal_workers import default_workers

    t0 = time.perf_counter()
    objects = tuple(objects)
    if judge_samples > 0:
        selection_goal_samples(robot, objects, goal, judge_samples, workers=default_workers())
    if ends > 0:
        rare_goal_configurations(robot, objects, goal, ends, workers=default_workers())
    return time.perf_counter() - t0


def witness_plan(method: str, goal_policy: str, method_options: Any) -> dict:
    """The witness searches an attack uses, as ``task_witness``'s keyword arguments:
    ``TaskOptions.witness_seeds``, ``witness_ends`` and ``selection_samples`` (the judging
    goal set, when there is more than one candidate to judge) for ``task`` under ``solvable``,
    else the task's witness alone."""
    from advocc_ros.attack.task import TaskOptions

    if method != 'task' or goal_policy != 'solvable':
        return {'seeds': 1, 'ends': 0}
    opts = method_options if isinstance(method_options, TaskOptions) else TaskOptions()
    judged = opts.draws > 1 or opts.witness_seeds > 1 or opts.witness_ends > 0
    return {'seeds': opts.witness_seeds, 'ends': opts.witness_ends,
            'judge_samples': opts.selection_samples if judged else 0}


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
    search = task_witness(robot, objects, q_init, goal,
                          **witness_plan(method, policy, options.get('method_options')))
    result = attack(heatmap, robot, objects, q_init, goal, budget, method, cfg,
                    certify=certify, witness=search.candidates, **options)
    stats = dict(result.stats, witness_search_ms=round(search.search_s * 1e3, 3),
                 judge_goals_ms=round(search.goals_s * 1e3, 3))
    if result.status == AttackStatus.NO_WITNESS:
        return dataclasses.replace(result, stats=stats, message=no_witness_message())
    return dataclasses.replace(result, stats=stats)


def no_witness_message() -> str:
    """Why a ``solvable`` attack was refused after the witness search found nothing."""
    from advocc_ros.planning.witness import WITNESS_TIME_S

    return ('no witness: RRTConnect found no path into the goal region on the unattacked scene '
            f'within {WITNESS_TIME_S:g} s (or the search failed), so no attack can be certified '
            'to keep a solution')


__all__ = ['WitnessSearch', 'attack_task', 'needs_witness', 'no_witness_message',
           'task_witness', 'witness_plan']
