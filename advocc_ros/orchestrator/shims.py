"""The planner-shim pool as the run loop sees it: shim states, the ``ShimPool`` interface, plan
jobs and answers without message types, and the planner queries of in-the-loop attacks.

The ROS implementation is :class:`advocc_ros.orchestrator.rospool.RosShimPool`; the run loop
(``orchestrator/run.py``) only talks to this interface, so it runs against a fake pool in tests.
"""

from __future__ import annotations

import dataclasses
import enum
import queue
import threading
from typing import Any, Protocol

import numpy as np


class ShimState(enum.StrEnum):
    """starting -> sync -> idle <-> busy; dead when it cannot be used any more.

    The pool moves a shim from starting to sync to idle (it knows how to ask a shim what it
    holds); the run loop moves it between idle and busy, and restarts or drops it.
    """

    STARTING = 'starting'
    SYNC = 'sync'
    IDLE = 'idle'
    BUSY = 'busy'
    DEAD = 'dead'


@dataclasses.dataclass
class Shim:
    """A planner shim serving this scene and what it is doing."""

    name: str
    """Fully qualified node name, e.g. ``/advocc_shim_table_pick_0``."""
    external: bool = False
    """Not started by us (another host): dropped, never restarted."""
    state: ShimState = ShimState.STARTING
    since: float = 0.0
    """``time.monotonic()`` of the last state change [s]."""
    trial: Any = None
    """The Trial (or in-the-loop query) in flight."""
    deadline: float = 0.0
    """``time.monotonic()`` after which an unanswered plan request marks the shim hung [s]."""
    served: int = 0
    handles: Any = None
    """The pool's own per-shim data (service clients, futures); the loop never reads it."""


@dataclasses.dataclass(frozen=True)
class PlanJob:
    """One plan request to a shim."""

    q_start: np.ndarray
    """Start configuration (nq,) [rad]."""
    goal: Any
    """``advocc_ros.model.scene.GoalRegion``."""
    planner_id: str
    time_budget_s: float
    seed: int


@dataclasses.dataclass(frozen=True)
class PlanAnswer:
    """A shim's answer to one plan request."""

    status: str
    """``ErrorCodes`` name (``'SUCCESS'``, ``'INTERNAL_ERROR'``, ...), or the number as text."""
    error_code: int
    message: str
    planning_time_s: float
    waypoints: int
    path: np.ndarray | None = None
    """Waypoints (N, nq) [rad] of a SUCCESS, else None."""
    first_solution_s: float | None = None
    """Request to the first exact solution [s] of a SUCCESS, else None."""


class CallFailed(RuntimeError):
    """A service call that got no answer (dead or hung node)."""


class ShimPool(Protocol):
    """What the run loop needs from the planner shims of one scene."""

    shims: list[Shim]

    def inject(self, objects: tuple) -> None:
        """Replace the injected objects by ``objects``; idle and syncing shims must re-sync."""

    def sync(self, shim: Shim, now: float) -> str | None:
        """Advance a starting or syncing shim (to sync, idle or dead) without blocking.

        Returns why the shim must be restarted (it did not come up), else None.
        """

    def plan(self, shim: Shim, job: PlanJob) -> None:
        """Send ``job`` to an idle shim without waiting for the answer."""

    def poll(self, shim: Shim) -> PlanAnswer | None:
        """The answer to the shim's request, None while in flight; ``CallFailed`` if it failed."""

    def exit_code(self, shim: Shim) -> int | None:
        """The exit code of a shim process we started that has exited, else None."""

    def restart(self, shim: Shim) -> None:
        """Forget the request in flight, restart the shim's process; the shim starts again."""

    def drop(self, shim: Shim) -> None:
        """Forget the request in flight and stop using the shim (dead)."""

    def output(self, shim: Shim) -> str:
        """The last lines the shim printed (for error messages)."""

    def discover(self, wait: bool = False) -> None:
        """Add external shims of this ROS domain (``wait``: give discovery a moment)."""

    def spin(self, timeout_s: float) -> None:
        """Process answers for up to ``timeout_s``."""

    def close(self) -> None:
        """Remove the injected objects, stop the shims we started."""


class PlanQuery:
    """One planner query of a planner-in-the-loop attack, answered by a shim."""

    def __init__(self, q_start, obstacles: tuple, goal, planner_id: str, time_budget_s: float,
                 seed: int):
        self.q_start, self.obstacles, self.goal = np.asarray(q_start, float), obstacles, goal
        self.planner_id, self.time_budget_s, self.seed = planner_id, time_budget_s, seed
        self.key = tuple((tuple(np.round(sh.pose.position_m, 9)), tuple(sh.dims))
                         for o in obstacles for sh in o.shapes)
        self.result = None
        self.event = threading.Event()

    def done(self, answer: PlanAnswer, nq: int) -> None:
        """Turn a shim's answer into the ``PlanResult`` the optimiser expects."""
        from advocc_ros.planning.types import PlanResult, PlanStatus

        try:
            status = PlanStatus(int(answer.error_code))
        except ValueError:  # CRASH, FAILURE, a code we do not know: not a planning outcome
            status = PlanStatus.INTERNAL_ERROR
        path = answer.path if status == PlanStatus.SUCCESS and answer.path is not None \
            else np.zeros((0, nq))
        stats = {}
        if len(path) > 1:
            stats['path_length_rad'] = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        self.result = PlanResult(status, answer.message, path, float(answer.planning_time_s),
                                 stats)
        self.event.set()


class ShimQueries:
    """:class:`advocc_ros.attack.pfa.QueryPlanner` backed by the planner shims.

    Called from the optimiser's threads; the orchestrator's main thread (which owns every ROS
    handle) injects each query's obstacles into all shims, waits until they hold them, and plans
    on them. Queries with the same obstacles run in parallel on different shims.
    """

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))
        self.requests: queue.SimpleQueue = queue.SimpleQueue()
        self.aborted = threading.Event()

    def __call__(self, q_start, obstacles, goal, planner_id, time_budget_s, seed):
        query = PlanQuery(q_start, tuple(obstacles), goal, planner_id, time_budget_s, seed)
        self.requests.put(query)
        while not query.event.wait(0.2):
            if self.aborted.is_set():
                raise RuntimeError('the benchmark stopped')
        return query.result
