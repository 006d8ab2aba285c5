"""A problem's threads capped at the Ray CPUs it holds.

The caps are environment variables, read once when each library starts its pool, so they must
be in a task's worker before Python starts: a local Ray is started with them (its processes, and
so its workers, inherit them); a cluster's tasks get them as their runtime environment (~5 s for
each new worker to set up, measured on a 2-core AMD EPYC, so the local Ray does without)."""

from __future__ import annotations

import contextlib
import os
from typing import Iterator

THREAD_ENV = ('ADVOCC_THREADS', 'OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')
"""Set to a task's CPUs in its worker's environment: this package's thread pools
(``limits.worker_threads``: its C++ pools and the kernels' parallel loops), OpenMP and the
BLAS libraries."""


def task_threads(cpus: float) -> int:
    """Threads of a task that holds ``cpus`` Ray CPUs (at least one)."""
    return max(1, int(cpus))


def thread_caps(cpus: float) -> dict[str, str]:
    """``THREAD_ENV``, each set to the threads of a task holding ``cpus`` CPUs."""
    return dict.fromkeys(THREAD_ENV, str(task_threads(cpus)))


@contextlib.contextmanager
def inherited(caps: dict[str, str]) -> Iterator[None]:
    """``caps`` in this process's environment while processes it starts inherit them; the
    environment as it was afterwards."""
    before = {key: os.environ.get(key) for key in caps}
    os.environ.update(caps)
    try:
        yield
    finally:
        for key, value in before.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


__all__ = ['THREAD_ENV', 'inherited', 'task_threads', 'thread_caps']
