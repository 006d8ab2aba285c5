"""The ``task`` attack over several witnesses: keep the one that leaves planners the fewest goals.

Under the ``solvable`` policy the boxes keep one witness valid, so the witness decides which goal
configurations stay free: those whose body stays near its last one. The task's own witness ends
where RRTConnect's goal sampler happened to land first, often in a common IK branch, and
planners sample that branch often. ``attack.edges`` also hands the attack witnesses to the goal
configurations the planners' goal samplers land on least often
(``attack.goals.rare_goal_configurations``, ``planning.end_witnesses``). The attack spreads
``TaskOptions.draws`` over the witnesses (at least one each, the task's witness first) and keeps
the attack that leaves the fewest of the selection goal samples valid, the score the draws are
kept by (``attack.task``; ties: more covered mass, then the earlier witness). No planner is
queried here.

Measured before it was built (scratch experiment, 10 trials x 5 s, M = 10, 8 draws per witness,
the task's witness against the best of it and six rare ends, RRTConnect / PRM* / BKPIECE1 PSR):
table_pick 80 / 30 / 30 -> 30 / 20 / 20 %, bookshelf 90 / 70 / 50 -> 30 / 40 / 10 %,
table_under_pick 0 / 0 / 0 both; held-out goal poses left valid 2.9 -> 0.3 % and 17 -> 8.7 %.
The bench figures with the defaults are in docs/results.md.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from advocc_ros.attack.goals import GoalSamples
from advocc_ros.attack.types import AttackResult


def draws_per_witness(draws: int, witnesses: int) -> list[int]:
    """``draws`` spread over ``witnesses`` as evenly as possible, the first ones first; every
    witness gets at least one draw."""
    return [max(1, draws // witnesses + (1 if i < draws % witnesses else 0))
            for i in range(witnesses)]


def attack_over_witnesses(run: Callable, witnesses: tuple, options,
                          judge: Callable[[], GoalSamples]) -> AttackResult:
    """The kept attack of ``run(witness, options)`` (``attack`` with the rest fixed) over
    ``witnesses`` (module docstring); ``options`` is the ``TaskOptions`` whose draws are
    spread, ``judge()`` the selection goal samples. A request the first attack refuses is
    answered by it. The kept result's ``compute_s`` is the sum over all attacks."""
    draws = draws_per_witness(options.draws, len(witnesses))
    results = [run(witnesses[0], dataclasses.replace(options, draws=draws[0]))]
    if not results[0].status.ok:
        return results[0]
    results += [run(w, dataclasses.replace(options, draws=d))
                for w, d in zip(witnesses[1:], draws[1:])]
    samples = judge()
    scores = []
    for i, result in enumerate(results):
        centers = np.array([o.shapes[0].pose.position_m for o in result.obstacles])
        valid = samples.valid_fraction(centers.reshape(-1, 3), result.box_size_m)
        ok = result.status.ok
        scores.append((not ok, 1.0 if valid is None or not ok else valid,
                       -result.total_mass, i))
    kept = min(scores)[3]
    stats = dict(results[kept].stats, task_witnesses=len(witnesses), task_witness_kept=kept,
                 task_witness_goal_valid=[None if s[0] else round(s[1], 6) for s in scores],
                 task_draws=options.draws, task_witness_draws=draws)
    return dataclasses.replace(results[kept], stats=stats,
                               compute_s=sum(r.compute_s for r in results))


__all__ = ['attack_over_witnesses', 'draws_per_witness']
