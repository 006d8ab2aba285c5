"""Hardness beyond PSR: time to first solution, PSR at several budgets, the PT ratio.

Sampling planners have heavy-tailed run times in narrow passages, so one PSR at one budget hides
most of what an attack does. Every trial records ``first_solution_s`` (request to the first
exact solution, ``advocc_ros.planning.PlanResult``); from one set of runs at budget B:

- ``psr_at[t]``: share of trials whose first solution came by t, for every t <= B: an anytime
  view of the budget-B runs, not a run at budget t. Up-front goal sampling may use a share of B
  (``PlanningConfig.ik_time_fraction``), and where the boxes leave few goal configurations it
  does, so PSR@t of a longer run can be lower than the PSR of a run at budget t;
- median and p90 of the time to first solution, failures counted at the budget B;
- PT ratio: attacked / unattacked median of that time (the slowdown an attack causes).

A success without ``first_solution_s`` (an answer that carried no stats) counts its planning
time, an upper bound; such rows say so with ``first_solution_measured: False`` and get no
``psr_at``. No ROS.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

PSR_TIMES_S = (1.0, 2.0, 5.0, 30.0)
"""Budgets [s] at which PSR is read off the time to first solution (those <= the run's)."""


def time_key(t_s: float) -> str:
    """The key of budget ``t_s`` in ``psr_at`` (``'1'``, ``'2.5'``): JSON objects need text."""
    return f'{t_s:g}'


def solution_times(rows: Iterable[dict]) -> tuple[np.ndarray, bool]:
    """Per trial, the time to first solution [s] (``inf`` for a failure), and whether every
    success measured it (else its planning time stands in)."""
    times, measured = [], True
    for row in rows:
        if not row['success']:
            times.append(np.inf)
            continue
        first = row.get('first_solution_s')
        measured = measured and first is not None
        times.append(float(first if first is not None else row['planning_time_s']))
    return np.asarray(times, dtype=float), measured


def psr_at(times: np.ndarray, t_s: float) -> float | None:
    """Share of trials whose first solution came by ``t_s``; None without trials."""
    return float(np.mean(times <= t_s)) if len(times) else None


def time_summary(rows: Iterable[dict], time_budget_s: float,
                 budgets_s: tuple[float, ...] = PSR_TIMES_S) -> dict:
    """The hardness fields of a table row (see the module docstring)."""
    times, measured = solution_times(rows)
    capped = np.minimum(times, time_budget_s)
    psr = {time_key(t): psr_at(times, t) for t in budgets_s if t <= time_budget_s + 1e-9}
    return {
        'first_solution_median_s': float(np.median(capped)) if len(times) else None,
        'first_solution_p90_s': float(np.quantile(capped, 0.9)) if len(times) else None,
        'first_solution_measured': measured,
        'psr_at': psr if measured else {},
    }


def pt_ratio(attacked: dict | None, unattacked: dict | None) -> float | None:
    """Attacked / unattacked median time to first solution (timeouts at the budget), from two
    table rows; None when either is missing or the unattacked median is 0."""
    if not attacked or not unattacked:
        return None
    num, den = attacked.get('first_solution_median_s'), unattacked.get('first_solution_median_s')
    if num is None or not den:
        return None
    return float(num) / float(den)
