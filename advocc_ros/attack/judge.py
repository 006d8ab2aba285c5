"""How ``task`` under ``solvable`` keeps one of its candidate attacks (draws, witnesses).

Planner-free, two scores per candidate:

1. goal configurations left valid: of the selection set, drawn the way the planners' goal
   samplers draw theirs (``attack.goals.selection_goal_samples``); a planner that never samples
   a valid goal fails ("goal not sampled");
2. passage left free: the fraction of a tight tube around the candidate's witness
   (``TaskOptions.passage_samples`` witness states, each plus N(0, ``PASSAGE_RAD``) per joint,
   collision-free on the unattacked scene) that no box touches. The lower, the closer the
   boxes hug the witness: a narrow passage, which is what makes sampling planners time out.
   ``passage_samples`` 0 leaves the goals alone to decide.

Candidates whose goal counts differ from the fewest by less than sampling noise (two standard
deviations of the difference of two counts, ``|n - n_min| <= 2 sqrt(n + n_min)``) are ties;
among them the narrowest passage wins, then fewer goals, then the order given (draw 0, the
task's own witness first).

Why both. Measured on the 14 candidates of seed 0, M = 10 (the task's witness 8 draws, three
rare-end witnesses 2 each), 8 trials x 5 s per candidate, RRTConnect + PRM* PSR, rank correlation
across all 14: on box the goal count predicts nothing (-0.22; the fewest goals, 14 of 1,024,
gave 38 / 50 %, the 21-goal draw 0 / 12.5 %) and the passage 0.81; on table_pick the goal count
0.90 and the passage 0.27. Goals alone kept box's 14-goal draw; the rule keeps the 21-goal one
(tied within noise, narrower passage) and table_pick's 0-goal one as before. Rows:
``docs/results/issue27_hard/judge``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from advocc_ros.attack.goals import GoalSamples

PASSAGE_RAD = 0.05
"""Standard deviation of the tube's perturbation per joint [rad]: 0.05 tracked PSR on box,
0.1 and 0.2 less (rank correlation 0.81 / 0.67 / -0.42, same rows)."""
PASSAGE_SEED = 0


@dataclasses.dataclass(frozen=True)
class Judged:
    """One candidate attack's scores (module docstring)."""

    goals_valid: int
    """Selection goal configurations no box touches."""
    goals: int
    """Selection goal configurations in all (0: the goal has no IK solution)."""
    passage_free: float
    """Fraction of the witness's tight tube no box touches (1.0 without tube samples)."""

    @property
    def goal_fraction(self) -> float | None:
        return self.goals_valid / self.goals if self.goals else None


def judge(goals: GoalSamples, passage: GoalSamples, centers_m: np.ndarray,
          box_size_m: float) -> Judged:
    """The scores of the boxes at ``centers_m`` (exact coal checks, ``GoalSamples``)."""
    free = passage.valid_mask(centers_m, box_size_m)
    return Judged(int(goals.valid_mask(centers_m, box_size_m).sum()), len(goals.Q),
                  float(free.mean()) if len(free) else 1.0)


def kept_index(judged: list[Judged]) -> int:
    """Index of the candidate kept by the rule of the module docstring."""
    fewest = min(j.goals_valid for j in judged)
    ties = [i for i, j in enumerate(judged)
            if j.goals_valid - fewest <= 2 * math.sqrt(j.goals_valid + fewest)]
    return min(ties, key=lambda i: (judged[i].passage_free, judged[i].goals_valid, i))


__all__ = ['PASSAGE_RAD', 'Judged', 'judge', 'kept_index']
