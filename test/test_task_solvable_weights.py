"""Method ``task`` under the ``solvable`` policy: one weight tier with a goal share (issue 27)."""

import numpy as np
import pytest

from advocc_ros.attack.task import TaskOptions, shared_weights


@pytest.mark.parametrize('share', [0.05, 0.5, 0.9])
def test_goal_rows_hold_their_share_of_the_total_weight(share):
    rng = np.random.default_rng(0)
    w_goal, w_app = rng.uniform(0.01, 1.0, 40), rng.uniform(0.0, 1.0, 600)
    weights = shared_weights(w_goal, w_app, share)
    np.testing.assert_array_equal(weights[40:], w_app)
    assert weights[:40].sum() / weights.sum() == pytest.approx(share)
    np.testing.assert_allclose(weights[:40] / w_goal, weights[0] / w_goal[0])  # order kept


def test_without_approaches_or_goals_the_weights_stay():
    w = np.array([0.2, 0.4])
    np.testing.assert_array_equal(shared_weights(w, np.zeros(0), 0.5), w)
    np.testing.assert_array_equal(shared_weights(np.zeros(0), w, 0.5), w)


def test_options_refuse_shares_outside_their_range():
    for bad in ({'goal_share': 1.0}, {'goal_share': -0.1}):
        with pytest.raises(ValueError, match='goal_share'):
            TaskOptions(**bad)
