"""The one cache facility: bounded, thread-safe, keyed by content.

Derived data that costs milliseconds to seconds and is asked for again and again (convex hulls
of a robot's links, link look-up tables, a task's goal samples and witness, a cloud's octree)
is kept per process. Every such cache is a :class:`BoundedCache`: least recently used entries go
first, so a long-running node does not grow without bound, and keys are content hashes (robot
hash, task hash, point hash), never ``id()`` of an object that may be freed and reused.
"""

from __future__ import annotations

import collections
import contextlib
import os
import pathlib
import threading
from typing import Callable, Generic, Hashable, TypeVar

V = TypeVar('V')

CACHE_ENV = 'ADVOCC_WITNESS_CACHE'
"""Environment variable: the on-disk cache's directory, or ``off``."""


def user_cache_root() -> pathlib.Path:
    """The user's cache folder of this tool: ``$XDG_CACHE_HOME/advocc_ros`` (default
    ``~/.cache/advocc_ros``)."""
    base = os.environ.get('XDG_CACHE_HOME') or pathlib.Path.home() / '.cache'
    return pathlib.Path(base) / 'advocc_ros'


def disk_cache_dir() -> pathlib.Path | None:
    """Where a task's witness and goal sample, and a robot's link tables, are kept between
    processes:
    ``$ADVOCC_WITNESS_CACHE`` (``off``: nowhere), by default
    ``$XDG_CACHE_HOME/advocc_ros/witness`` (``~/.cache/advocc_ros/witness``). What is read back
    is checked again before it is used."""
    value = os.environ.get(CACHE_ENV, '')
    if value == 'off':
        return None
    if value:
        return pathlib.Path(value)
    return user_cache_root() / 'witness'


@contextlib.contextmanager
def disk_cache_at(value: str):
    """``$ADVOCC_WITNESS_CACHE`` set to ``value`` (a folder, or ``off``) inside the block, and
    as it was after it."""
    saved = os.environ.get(CACHE_ENV)
    os.environ[CACHE_ENV] = value
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(CACHE_ENV, None)
        else:
            os.environ[CACHE_ENV] = saved


class BoundedCache(Generic[V]):
    """A least-recently-used map with at most ``max_entries`` entries, safe across threads.

    ``get_or_make`` builds a missing value outside the lock (a build may take seconds and
    another thread may want another key meanwhile); when two threads build the same key at
    once, the first value stored is kept and returned to both.
    """

    def __init__(self, name: str, max_entries: int, per_task: bool = False):
        if max_entries < 1:
            raise ValueError(f'cache {name}: max_entries must be >= 1, got {max_entries}')
        self.name, self.max_entries = name, max_entries
        self._entries: collections.OrderedDict[Hashable, V] = collections.OrderedDict()
        self._lock = threading.Lock()
        if per_task:
            _PER_TASK.append(self)

    def get(self, key: Hashable) -> V | None:
        with self._lock:
            if key not in self._entries:
                return None
            self._entries.move_to_end(key)
            return self._entries[key]

    def put(self, key: Hashable, value: V) -> V:
        """Store ``value`` unless ``key`` is already there; the stored value."""
        with self._lock:
            value = self._entries.setdefault(key, value)
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)
            return value

    def get_or_make(self, key: Hashable, make: Callable[[], V]) -> V:
        value = self.get(key)
        return self.put(key, make()) if value is None else value

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._entries


_PER_TASK: list[BoundedCache] = []
"""The caches of what an attack on a new task computes again (``per_task``): its goal sets, the
witness bodies, the passage tube; not the witness searches (``advocc perf attack`` times them
apart), robot models, link tables or collision worlds."""


def clear_task_caches() -> None:
    """Forget every per-task cache in this process, so that the next attack pays what an attack
    on a new task pays (``advocc perf attack``'s cold timings)."""
    for cache in _PER_TASK:
        cache.clear()


def task_caches() -> tuple[BoundedCache, ...]:
    """The per-task caches made so far in this process: those ``clear_task_caches`` forgets."""
    return tuple(_PER_TASK)


__all__ = ['BoundedCache', 'clear_task_caches', 'task_caches']
