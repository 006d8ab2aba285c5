"""OMPL's discrete motion check with a motion's states checked in one C++ call.

OMPL's ``DiscreteMotionValidator`` calls the Python validity checker once per interpolated state
(~0.01 rad apart), so a long extension costs a hundred Python round trips. This validator makes
the same states (``validSegmentCount`` segments, ``RealVectorStateSpace``'s interpolation
``from + (to - from) * t`` in the same floating-point operations), in the same order (the end
state first and then bisection order for the yes/no query; in order for the last-valid query,
which BKPIECE1 uses), and hands them to ``CollisionWorld.first_collision``, which stops at the
first collision as OMPL does. Verdicts, last-valid states and the number of states checked are
OMPL's; only the Python between states is gone.
"""

from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=4096)
def _bisection_order(nd: int) -> np.ndarray:
    """Interior indices 1..nd-1 in the order OMPL's ``checkMotion(s1, s2)`` visits them."""
    order, queue, head = [], [(1, nd - 1)] if nd >= 2 else [], 0
    while head < len(queue):
        lo, hi = queue[head]
        head += 1
        mid = (lo + hi) // 2
        order.append(mid)
        if lo < mid:
            queue.append((lo, mid - 1))
        if hi > mid:
            queue.append((mid + 1, hi))
    return np.array(order, dtype=float)


def make_motion_validator(ob, si, space, world, nq: int, checks: list):
    """An ``ob.MotionValidator`` for ``si`` over ``world``; adds states checked to
    ``checks[0]``."""

    class BatchMotionValidator(ob.MotionValidator):
        def checkMotion(self, s1, s2, lastValid=None):  # noqa: N802,N803 (OMPL API)
            a = np.array([s1[i] for i in range(nq)])
            b = np.array([s2[i] for i in range(nq)])
            nd = space.validSegmentCount(s1, s2)
            if lastValid is None:
                t = _bisection_order(nd) / float(nd)
                Q = np.vstack([b[None], a + (b - a) * t[:, None]])
            else:
                t = np.arange(1, nd, dtype=float) / float(nd)
                Q = np.vstack([a + (b - a) * t[:, None], b[None]])
            first = world.first_collision(Q)
            checks[0] += len(Q) if first < 0 else first + 1
            if first < 0:
                return True
            if lastValid is not None:
                # OMPL: the last valid fraction is (j - 1) / nd for the first invalid state j
                # (the end state counts as j = nd).
                lastValid.second = first / float(nd)
                if lastValid.first is not None:
                    q = a + (b - a) * lastValid.second
                    for i in range(nq):
                        lastValid.first[i] = float(q[i])
            return False

    return BatchMotionValidator(si)
