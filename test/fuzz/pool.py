"""A pool of worker processes with a watchdog: a hang is detected and killed, not suffered.

Each worker imports a target module, calls its ``setup(context)`` once (imports, robot model)
and says ready; then for each job it calls ``run(state, job)`` and sends back
``(category, detail)``. The parent gives each job ``timeout_s`` of wall time: past that the
worker is killed (SIGKILL) and the job is a hang; a worker that dies mid-job (signal, abort,
``os._exit``) makes the job a crash. Either way a fresh worker takes the slot.
"""

from __future__ import annotations

import dataclasses
import importlib
import multiprocessing
import time
import traceback
from multiprocessing.connection import wait
from typing import Any, Callable

_START_TRIES = 3
"""Workers that die before they are ready, in a row, before the pool gives up."""


def _worker(conn, target: str, context: dict) -> None:
    module = importlib.import_module(target)
    state = module.setup(context)
    conn.send(('ready', None, 0.0))
    while True:
        job = conn.recv()
        if job is None:
            return
        t0 = time.perf_counter()
        try:
            category, detail = module.run(state, job)
        except BaseException as exc:  # a bug in the target itself, reported as a crash
            category, detail = 'crash', 'fuzz target: ' + ''.join(
                traceback.format_exception_only(type(exc), exc)).strip()
        conn.send((category, detail, time.perf_counter() - t0))


@dataclasses.dataclass
class _Slot:
    proc: Any = None
    conn: Any = None
    ready: bool = False
    job: Any = None
    started: float = 0.0


def run_pool(jobs: list, target: str, context: dict, workers: int, timeout_s: float,
             record: Callable[[Any, str, str, float], None]) -> None:
    """Run every job of ``jobs`` in ``workers`` processes of ``target``; ``record(job,
    category, detail, seconds)`` is called once per job, in completion order."""
    ctx = multiprocessing.get_context('spawn')  # no fork of a parent that may run DDS threads
    pending = list(reversed(jobs))
    slots = [_Slot() for _ in range(max(1, workers))]
    failed_starts = 0

    def start(slot: _Slot) -> None:
        parent, child = ctx.Pipe()
        slot.proc = ctx.Process(target=_worker, args=(child, target, context), daemon=True)
        slot.proc.start()
        child.close()
        slot.conn, slot.ready, slot.job = parent, False, None

    def kill(slot: _Slot) -> None:
        slot.proc.kill()
        slot.proc.join(10)
        slot.conn.close()

    for slot in slots:
        start(slot)
    try:
        while pending or any(s.job is not None for s in slots):
            for slot in slots:
                if slot.ready and slot.job is None and pending:
                    slot.job, slot.started = pending.pop(), time.monotonic()
                    slot.conn.send(slot.job)
            busy = [s.started + timeout_s for s in slots if s.job is not None]
            wait_s = max(0.0, min(busy) - time.monotonic()) if busy else 1.0
            ready = wait([s.conn for s in slots], timeout=min(wait_s, 1.0))
            for slot in slots:
                if slot.conn in ready:
                    try:
                        category, detail, seconds = slot.conn.recv()
                    except (EOFError, OSError):
                        kill(slot)
                        if slot.job is None:
                            failed_starts += 1
                            if failed_starts >= _START_TRIES:
                                raise RuntimeError(f'{target}: workers die at start-up '
                                                   f'(exit code {slot.proc.exitcode})')
                        else:
                            record(slot.job, 'crash', f'worker died (exit code '
                                   f'{slot.proc.exitcode})', time.monotonic() - slot.started)
                        start(slot)
                        continue
                    if category == 'ready':
                        slot.ready, failed_starts = True, 0
                    else:
                        record(slot.job, category, detail, seconds)
                        slot.job = None
                elif slot.job is not None and time.monotonic() - slot.started > timeout_s:
                    kill(slot)
                    record(slot.job, 'hang', f'no outcome within {timeout_s:.0f} s',
                           time.monotonic() - slot.started)
                    start(slot)
    finally:
        for slot in slots:
            if slot.proc.is_alive():
                try:
                    slot.conn.send(None)
                except OSError:
                    pass
                slot.proc.join(5)
                if slot.proc.is_alive():
                    kill(slot)
