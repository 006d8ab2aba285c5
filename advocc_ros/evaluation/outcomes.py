"""How a trial ended, from its status: a success, one of the planner's failure modes, or an
internal error.

Only the planner's own answers measure the scene: no collision-free goal configuration sampled
(``GOAL_IN_COLLISION``, ``NO_IK_SOLUTION``: the planner's goal sampler gave up; whether the goal
is really blocked is the task's ``solvable`` verdict, not the planner's word), out of time
(``TIMED_OUT``: the paths were occluded), no path found (``PLANNING_FAILED``) or a solution
with a waypoint in collision (``INVALID_MOTION_PLAN``: the planner's motion check stepped over
an obstacle; MoveIt's ``ValidateSolution`` adapter refuses such a plan the same way). Outside
victims (``advocc_ros.planning.victims``) add two of their own: none of the goal configurations
they were given is valid in their collision model (``GOAL_STATE_INVALID``: the task fails in
their model, the planner did not), and a path free in their model that collides in ours
(``MODEL_MISMATCH``: meshes vs convex hulls; not a success, not a planning failure). Anything
else (``INTERNAL_ERROR`` from a planner that raised or died, a "success" whose path collides
after all, ``CRASH``/``FAILURE``/an unknown code from a shim, a rejected request, a record that
contradicts itself) is an internal error: a bug or a dead process must not lower PSR and pass for a
successful attack, so internal errors stay out of PSR's denominator, are counted on their own,
and a benchmark cell with more than ``MAX_INTERNAL_ERROR_FRACTION`` of them fails the run.
"""

from __future__ import annotations

SUCCESS = 'success'
INTERNAL_ERROR = 'internal error'
FAILURE_MODES = ('goal not sampled', 'timed out', 'planning failed', 'invalid path',
                 'goal invalid for victim', 'model mismatch')
"""The planner's failure modes, in table order."""
_MODES = {'GOAL_IN_COLLISION': 'goal not sampled', 'NO_IK_SOLUTION': 'goal not sampled',
          'TIMED_OUT': 'timed out', 'PLANNING_FAILED': 'planning failed',
          'INVALID_MOTION_PLAN': 'invalid path', 'GOAL_STATE_INVALID': 'goal invalid for victim',
          'MODEL_MISMATCH': 'model mismatch'}
MAX_INTERNAL_ERROR_FRACTION = 0.05
"""A benchmark cell with a larger share of internal errors fails the run."""


def outcome(status: str) -> str:
    """``success``, a failure mode or ``internal error`` for a status name (``PlanStatus`` or
    ``advocc_msgs/ErrorCodes``; a code without a name arrives as its number)."""
    if status == 'SUCCESS':
        return SUCCESS
    return _MODES.get(status, INTERNAL_ERROR)


def record_outcome(record: dict) -> str:
    """The outcome of a trial record; one whose ``success`` flag contradicts its status is an
    internal error."""
    kind = outcome(str(record.get('status', '')))
    if (kind == SUCCESS) != bool(record.get('success')):
        return INTERNAL_ERROR
    return kind


def too_many_internal_errors(row: dict) -> bool:
    """Whether a table row (``aggregate``) has more internal errors than the run may have."""
    return row['internal_errors'] > MAX_INTERNAL_ERROR_FRACTION * row['trials']


def internal_error_warning(row: dict, what: str = '') -> str | None:
    """The warning to print for a row with internal errors, else None."""
    if not row['internal_errors']:
        return None
    where = f'{what}: ' if what else ''
    return (f'warning: {where}{row["internal_errors"]} of {row["trials"]} trials were internal '
            'errors (the planner raised or died, not a planning outcome): left out of PSR')
