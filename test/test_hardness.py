"""Hardness beyond PSR: time to first solution, PSR at several budgets, PT ratio (hand values)."""

import json

import numpy as np
import pytest

from advocc_ros.evaluation.hardness import psr_at, pt_ratio, solution_times, time_summary
from advocc_ros.evaluation.metrics import TrialRecord, aggregate


def _rec(k, first_s, planning_s=None, status=None):
    if first_s is None:
        return TrialRecord(k, k, False, status or 'TIMED_OUT', planning_s or 5.0)
    return TrialRecord(k, k, True, 'SUCCESS', planning_s or first_s + 0.2,
                       min_manipulability=0.05, min_clearance_rad=0.03, jds_rad=1.0,
                       first_solution_s=first_s)


def test_psr_at_budgets_from_first_solution_times():
    # PRM*-like: every success ran to the 5 s budget, but first solved at 0.4 .. 3.0 s
    recs = [_rec(0, 0.4, 5.0), _rec(1, 1.0, 5.0), _rec(2, 1.7, 5.0), _rec(3, 3.0, 5.0),
            _rec(4, None)]
    row = aggregate(recs, time_budget_s=5.0)
    assert row['psr'] == 0.8
    assert row['psr_at'] == {'1': 0.4, '2': 0.6, '5': 0.8}  # '30' > the budget: not reported
    assert row['first_solution_median_s'] == pytest.approx(1.7)
    # p90 of [0.4, 1.0, 1.7, 3.0, 5.0 (timeout at the budget)]: 3.0 + 0.6 * 2.0
    assert row['first_solution_p90_s'] == pytest.approx(4.2)
    assert row['first_solution_measured'] is True
    assert json.loads(json.dumps(row))['psr_at']['5'] == 0.8


def test_thirty_second_column_when_the_budget_allows():
    row = time_summary([_rec(0, 12.0).to_data(), _rec(1, None, 30.0).to_data()], 30.0)
    assert row['psr_at'] == {'1': 0.0, '2': 0.0, '5': 0.0, '30': 0.5}
    assert row['first_solution_median_s'] == pytest.approx(21.0)


def test_missing_first_solution_is_an_upper_bound_and_flagged():
    rows = [dict(_rec(0, 0.3, 1.1).to_data(), first_solution_s=None), _rec(1, None).to_data()]
    times, measured = solution_times(rows)
    assert not measured
    np.testing.assert_array_equal(times, [1.1, np.inf])
    row = time_summary(rows, 5.0)
    assert row['psr_at'] == {} and row['first_solution_measured'] is False
    assert row['first_solution_median_s'] == pytest.approx((1.1 + 5.0) / 2)


def test_pt_ratio_counts_timeouts_at_the_budget():
    base = aggregate([_rec(k, 0.5) for k in range(4)], 5.0)
    attacked = aggregate([_rec(0, 1.0), _rec(1, None), _rec(2, None), _rec(3, 2.0)], 5.0)
    assert attacked['first_solution_median_s'] == pytest.approx(3.5)  # (2.0 + 5.0) / 2
    assert pt_ratio(attacked, base) == pytest.approx(7.0)
    assert pt_ratio(attacked, None) is None and pt_ratio(None, base) is None
    assert psr_at(np.array([]), 1.0) is None
