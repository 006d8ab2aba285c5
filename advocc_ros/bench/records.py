"""Per-trial records of a run folder: the append-only store, the run lock, the config check.

``RecordStore``: per-trial JSON lines, appended with flush + fsync, deduplicated by trial key on
load, tolerant of a truncated last line (a kill mid-write), so a re-run resumes exactly.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import pathlib
from typing import Any

from advocc_ros.bench.protocol import IDENTITY_FIELDS, BenchConfig, BenchError, Unit

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Records

class RecordStore:
    """Per-trial records as JSON lines; one line per finished trial, never two per key."""

    def __init__(self, path: str | pathlib.Path):
        self.path = pathlib.Path(path)
        self.records: dict[str, dict] = {}
        self.duplicates = 0
        self.bad_lines = 0
        self._load()

    def _load(self) -> None:
        if not self.path.exists():
            return
        raw = self.path.read_bytes()
        lines = raw.split(b'\n')
        tail = lines.pop()  # b'' when the file ends with a newline
        for i, line in enumerate(lines):
            self._take(line, i + 1)
        if tail:
            # A kill mid-append leaves a partial last line: keep it only if it is whole JSON.
            if self._take(tail, len(lines) + 1, warn=False):
                with open(self.path, 'ab') as handle:
                    handle.write(b'\n')
            else:
                log.warning('%s: dropping a truncated last line (%d bytes)', self.path,
                            len(tail))
                with open(self.path, 'r+b') as handle:
                    handle.truncate(len(raw) - len(tail))
            with open(self.path, 'rb+') as handle:
                os.fsync(handle.fileno())

    def _take(self, line: bytes, number: int, warn: bool = True) -> bool:
        if not line.strip():
            return True
        try:
            rec = json.loads(line)
            key = rec['key']
        except (ValueError, KeyError, TypeError):
            if warn:
                log.warning('%s:%d: skipping an unreadable record', self.path, number)
                self.bad_lines += 1
            return False
        if key in self.records:
            self.duplicates += 1  # only a foreign writer could do this: keep the first
        else:
            self.records[key] = rec
        return True

    def __contains__(self, key: str) -> bool:
        return key in self.records

    def __len__(self) -> int:
        return len(self.records)

    def append(self, record: dict) -> bool:
        """Append one finished trial durably; False if its key is already recorded."""
        key = record['key']
        if key in self.records:
            return False
        line = (json.dumps(record, sort_keys=True, allow_nan=False) + '\n').encode()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line)
            os.fsync(fd)
        finally:
            os.close(fd)
        self.records[key] = record
        return True


@contextlib.contextmanager
def run_lock(run_dir: pathlib.Path):
    """Exclusive lock on a run folder: two orchestrators on one folder would duplicate trials.
    The kernel drops it when the holder dies, even by SIGKILL."""
    run_dir.mkdir(parents=True, exist_ok=True)
    handle = open(run_dir / '.lock', 'w')
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise BenchError(f'{run_dir} is in use by another benchmark process') from None
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        handle.close()


def check_run_config(run_dir: pathlib.Path, cfg: BenchConfig) -> None:
    """Refuse to resume a run folder whose trials were measured under other settings."""
    path = run_dir / 'config.json'
    if not path.exists():
        return
    try:
        old = json.loads(path.read_text())['config']
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchError(f'{path}: unreadable ({exc}); remove it to start over') from None
    new = cfg.to_data()
    # A setting an older run folder does not record ran at its default (new settings default
    # to the old behaviour), so those folders still resume.
    default = BenchConfig().to_data()
    diff = [f'{k}: {old.get(k, default[k])!r} -> {new[k]!r}' for k in IDENTITY_FIELDS
            if old.get(k, default[k]) != new[k]]
    if diff:
        raise BenchError(f'{run_dir} holds trials measured with other settings ({"; ".join(diff)})'
                         '; use another --out folder')


def progress_summary(store: RecordStore, units: list[Unit]) -> dict[str, Any]:
    """Planned, finished and missing trials of a run plan."""
    planned = [t.key for u in units for t in u.trials]
    done = sum(1 for k in planned if k in store)
    return {'planned': len(planned), 'done': done, 'missing': len(planned) - done,
            'records': len(store), 'duplicates_on_load': store.duplicates,
            'bad_lines_on_load': store.bad_lines}
