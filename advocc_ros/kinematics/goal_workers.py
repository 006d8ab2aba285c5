"""Goal sampling with its IK spread over worker processes, giving the one-process result.

``GoalSampler.draw`` makes every random draw here, in the order one process makes them; the
workers run only each attempt's DLS, which draws nothing, and the results are taken in attempt
order. So the configurations are those of ``GoalSampler.attempt`` in a loop, bit for bit, in
about 1/N of the time: the 4,096 goal configurations that judge a ``solvable`` attack are
~30-60 s of IK in one process.

The workers are forked, as the heatmap build's are: they inherit the sampler (no robot to
load again) and, unlike spawned ones, never re-run the caller's ``__main__``. A forked child
runs only pinocchio's kinematics and numpy here: no ROS code, and no OpenMP region (the batched
collision checks use OpenMP, which is not fork-safe), so the collision check stays in the parent.
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import multiprocessing
import os
import signal

import numpy as np

from advocc_ros.kinematics.ik import GoalSampler, IkJob

log = logging.getLogger(__name__)

CHUNK = 8
"""Attempts per task sent to a worker (~40 ms of DLS)."""
CHUNKS_IN_FLIGHT_PER_WORKER = 3
"""Tasks queued ahead per worker: none idles, and few results past the n-th are wasted."""

_WORKER: dict = {}


MAX_WORKERS = 8
"""Each worker holds its own robot model (~150 MB with pinocchio and coal loaded)."""


def default_workers() -> int:
    """The CPUs this process may run on, at most ``MAX_WORKERS``."""
    return min(len(os.sched_getaffinity(0)), MAX_WORKERS)


def sample_goal_configurations(sampler: GoalSampler, n: int, max_attempts: int,
                               workers: int) -> list[np.ndarray]:
    """The valid configurations among ``sampler``'s next attempts, until ``n`` of them or
    ``max_attempts`` attempts in all: what ``sampler.attempt()`` in a loop returns.

    ``workers`` > 1 runs the DLS in that many forked processes; the sampler's stream is then
    left a few draws past the last attempt used. A pool that cannot start or dies raises
    ``OSError`` or ``BrokenProcessPool``.
    """
    found: list[np.ndarray] = []
    if workers <= 1:
        while len(found) < n and sampler.attempts < max_attempts:
            q = sampler.attempt()
            if q is not None:
                found.append(q)
        return found
    with concurrent.futures.ProcessPoolExecutor(
            workers, mp_context=multiprocessing.get_context('fork'), initializer=_start_worker,
            initargs=(sampler,)) as pool:
        in_flight: collections.deque = collections.deque()

        def submit() -> None:
            size = min(CHUNK, max_attempts - sampler.attempts)
            if size > 0:
                in_flight.append(pool.submit(_solve_all, [sampler.draw() for _ in range(size)]))

        for _ in range(CHUNKS_IN_FLIGHT_PER_WORKER * workers):
            submit()
        while in_flight and len(found) < n:
            for q in in_flight.popleft().result():
                q = sampler.accept(q)
                if q is not None:
                    found.append(q)
                    if len(found) == n:
                        break
            submit()
        pool.shutdown(cancel_futures=True)
    return found


def _start_worker(sampler: GoalSampler) -> None:
    """The forked copy of the parent's sampler (it only solves here). SIGINT is the parent's
    to handle; SIGTERM (how the pool ends a worker) kills."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _WORKER['sampler'] = sampler


def _solve_all(jobs: list[IkJob]) -> list[np.ndarray | None]:
    return [_WORKER['sampler'].solve(job) for job in jobs]


__all__ = ['default_workers', 'sample_goal_configurations']
