"""The planner-free judge of ``task``'s candidate attacks (``attack.judge``)."""

import pytest

from advocc_ros.attack.judge import Judged, kept_index


def _j(goals_valid: int, passage_free: float) -> Judged:
    return Judged(goals_valid, 1024, passage_free)


def test_goal_counts_within_noise_tie_and_the_narrower_passage_wins():
    # 14 and 21 of 1,024 differ by less than 2 sqrt(35) ~ 11.8: a tie.
    assert kept_index([_j(14, 0.55), _j(21, 0.45), _j(60, 0.10)]) == 1


def test_clearly_fewer_goals_win_over_any_passage():
    # 0 against 6: 6 > 2 sqrt(6) ~ 4.9, so the narrow passage of the second does not count.
    assert kept_index([_j(6, 0.01), _j(0, 0.90)]) == 1
    assert kept_index([_j(0, 0.50), _j(1, 0.56)]) == 0


def test_exact_ties_keep_fewer_goals_then_the_order_given():
    assert kept_index([_j(3, 0.5), _j(2, 0.5)]) == 1
    assert kept_index([_j(2, 0.5), _j(2, 0.5)]) == 0


def test_no_goal_samples_leave_the_passage_to_decide():
    none = [Judged(0, 0, 0.7), Judged(0, 0, 0.3)]
    assert kept_index(none) == 1
    assert none[0].goal_fraction is None and _j(512, 1.0).goal_fraction == pytest.approx(0.5)
