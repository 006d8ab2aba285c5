"""Starting and stopping node processes: the one way every advocc program does it."""

from __future__ import annotations

import ctypes
import json
import logging
import os
import pathlib
import signal
import subprocess
import sys
import time
from typing import Any

log = logging.getLogger(__name__)

_STOP_GRACE_S = 10.0
_PR_SET_PDEATHSIG = 1
_LIBC = ctypes.CDLL(None, use_errno=True)


def node_command(module: str, params: dict | None = None, remaps: dict | None = None
                 ) -> list[str]:
    """``python -m advocc_ros.nodes.<module> --ros-args -r k:=v ... -p k:=v ...``.

    ``params`` values: booleans as ``true``/``false``, lists as JSON arrays of strings (a YAML
    flow sequence, as ROS parses it), everything else as ``str(value)``.
    """
    args = [sys.executable, '-m', f'advocc_ros.nodes.{module}', '--ros-args']
    for key, value in (remaps or {}).items():
        args += ['-r', f'{key}:={value}']
    for key, value in (params or {}).items():
        if isinstance(value, bool):
            value = 'true' if value else 'false'
        elif isinstance(value, (list, tuple)):
            value = json.dumps([str(v) for v in value])
        args += ['-p', f'{key}:={value}']
    return args


def start_node(module: str, params: dict | None = None, remaps: dict | None = None,
               env: dict | None = None, log=None) -> subprocess.Popen:
    """A node as a child process; its output (stdout and stderr) goes to the text file ``log``."""
    return subprocess.Popen(node_command(module, params, remaps), env=env, stdout=log,
                            stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen, grace_s: float = 15.0) -> int:
    """SIGINT (a node's clean shutdown), then SIGKILL after ``grace_s``; the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def _die_with_parent() -> None:  # runs in the child between fork and exec
    _LIBC.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def node_name(text: str) -> str:
    """A valid ROS node name fragment."""
    out = ''.join(c if c.isalnum() or c == '_' else '_' for c in text)
    return out if out[:1].isalpha() else f'n_{out}'


class Child:
    """One node process: own process group, log file, restart with a count."""

    def __init__(self, name: str, module: str, params: dict[str, Any], env: dict,
                 log_dir: pathlib.Path):
        self.name, self.module, self.params, self.env = name, module, params, env
        self.log_path = log_dir / f'{name}.log'
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self.started_at = 0.0

    @property
    def restarts(self) -> int:
        return max(0, self.starts - 1)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc else None

    def start(self) -> None:
        args = node_command(self.module, self.params, {'__node': self.name})
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'ab') as handle:
            handle.write(f'\n=== start #{self.starts + 1} at {time.ctime()}: '
                         f'{" ".join(args)}\n'.encode())
            handle.flush()
            self.proc = subprocess.Popen(args, env=self.env, stdin=subprocess.DEVNULL,
                                         stdout=handle, stderr=subprocess.STDOUT,
                                         start_new_session=True, preexec_fn=_die_with_parent)
        self.starts += 1
        self.started_at = time.monotonic()
        log.info('started %s (pid %d)', self.name, self.proc.pid)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def _signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def stop(self, grace_s: float = _STOP_GRACE_S) -> int | None:
        """SIGINT to the group, SIGKILL after ``grace_s``; the group's leftovers are killed."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self._signal_group(signal.SIGINT)
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                log.warning('%s ignored SIGINT for %.0f s: SIGKILL', self.name, grace_s)
        self._signal_group(signal.SIGKILL)  # e.g. a planning worker left behind
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        return self.proc.returncode

    def restart(self) -> None:
        self.stop(grace_s=2.0)
        self.start()

    def tail(self, lines: int = 20) -> str:
        try:
            return '\n'.join(self.log_path.read_text(errors='replace').splitlines()[-lines:])
        except OSError:
            return ''


__all__ = ['Child', 'node_command', 'node_name', 'start_node', 'stop']
