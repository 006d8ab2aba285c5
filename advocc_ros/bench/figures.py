"""Figures of a benchmark run: PSR against the budget, trials solved against time."""

from __future__ import annotations

import pathlib

from advocc_ros.bench.protocol import PLANNER_LABELS as _PLANNER_TITLES
from advocc_ros.evaluation.figures import percent_axes, save_png  # sets matplotlib's backend

import matplotlib.pyplot as plt  # noqa: E402 (after the backend is set)
import numpy as np  # noqa: E402

_METHOD_STYLE = {'ours': ('tab:red', 'o'), 'random': ('tab:gray', 's'),
                 'pfa': ('tab:blue', '^'), 'pfa++': ('tab:green', 'v')}


def plot_psr_vs_budget(curves: dict[tuple[str, str], dict[int, float]],
                       out: str | pathlib.Path, title: str = '') -> None:
    """PSR [%] against the obstacle budget, one panel per planner and one line per method.

    ``curves[(planner, method)] = {budget: psr}`` (PSR as a fraction; budget 0 = unattacked).
    """
    planners = list(dict.fromkeys(p for p, _ in curves))
    fig, axes = plt.subplots(1, len(planners), figsize=(4.5 * len(planners), 3.8),
                             squeeze=False, constrained_layout=True)
    for ax, planner in zip(axes[0], planners):
        for (p, method), points in curves.items():
            if p != planner:
                continue
            budgets = sorted(points)
            color, marker = _METHOD_STYLE.get(method, (None, 'x'))
            ax.plot(budgets, [100 * points[b] for b in budgets], marker=marker, color=color,
                    label=method)
        ax.set_title(_PLANNER_TITLES.get(planner, planner))
        ax.set_xlabel('obstacle budget M')
        ax.set_ylabel('PSR [%]')
        percent_axes(ax)
    if title:
        fig.suptitle(title)
    save_png(fig, out)


_T_MIN_S = 0.01
"""Left end of the time axis [s] (log scale); faster solutions are drawn at it."""


def plot_time_to_solution(times: dict[tuple[str, str, int], np.ndarray], time_budget_s: float,
                          out: str | pathlib.Path, title: str = '') -> None:
    """Success against time: per (planner, method) panel, the empirical CDF of the time to
    first solution, one curve per budget m (m = 0, the unattacked scene, dashed in every panel
    of its planner); failures never arrive, so a curve ends at its PSR. The legend gives each
    curve's median and p90 (failures counted at the budget): heavy tails show as a long climb.

    ``times[(planner, method, m)]``: per trial [s], ``inf`` for a failure.
    """
    planners = list(dict.fromkeys(p for p, _, _ in times))
    methods = list(dict.fromkeys(m for _, m, b in times if b > 0)) or ['-']
    fig, axes = plt.subplots(len(planners), len(methods), squeeze=False, sharex=True,
                             figsize=(4.6 * len(methods), 3.4 * len(planners)),
                             constrained_layout=True)
    colors = plt.get_cmap('viridis')
    budgets = sorted({b for _, _, b in times if b > 0})
    for row, planner in enumerate(planners):
        for col, method in enumerate(methods):
            ax = axes[row][col]
            curves = [(b, times[(p, m, b)]) for (p, m, b) in times
                      if p == planner and (b == 0 or m == method)]
            for budget, values in sorted(curves, key=lambda c: c[0]):
                capped = np.minimum(values, time_budget_s)
                label = (f'{"unattacked" if budget == 0 else f"M={budget}"} (median '
                         f'{np.median(capped):.2f} s, p90 {np.quantile(capped, 0.9):.2f} s)')
                solved = np.sort(values[np.isfinite(values)])
                x = np.concatenate([[_T_MIN_S], np.maximum(solved, _T_MIN_S), [time_budget_s]])
                y = 100 * np.concatenate([[0], np.arange(1, len(solved) + 1),
                                          [len(solved)]]) / len(values)
                style = dict(color='black', ls='--') if budget == 0 else dict(
                    color=colors(budgets.index(budget) / max(1, len(budgets) - 1) * 0.85))
                ax.step(x, y, where='post', label=label, **style)
            ax.set_title(f'{_PLANNER_TITLES.get(planner, planner)}, {method}')
            ax.set_xscale('log')  # run times span decades; a heavy tail is a slow climb
            ax.set_xlabel('time to first solution [s]')
            ax.set_ylabel('trials solved [%]')
            ax.set_xlim(_T_MIN_S, time_budget_s)
            ax.set_ylim(-3, 103)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc='lower right')
    if title:
        fig.suptitle(title)
    save_png(fig, out)
