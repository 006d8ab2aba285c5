"""Starting and stopping node processes: the one way every advocc program does it.

A ``Child`` runs in a session (and process group) of its own, created by ``start_new_session``
without any Python code between fork and exec: a ``preexec_fn`` runs in the forked copy of a
process whose other threads (DDS, executors) may hold locks that copy can never take again.
For the same reason the child asks for ``PR_SET_PDEATHSIG`` itself (``die_with_parent``, called
by ``advocc_ros.nodes.run`` before rclpy starts). The group is signalled only while its leader is
unreaped (``os.waitid`` with ``WNOWAIT``): the leader's zombie keeps the group id from being
reused, so ``killpg`` cannot reach an unrelated group.
"""

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
PARENT_ENV = 'ADVOCC_DIE_WITH_PARENT'
"""Set by ``Child.start`` to the parent's pid: the child dies with that process."""


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


def die_with_parent() -> None:
    """In a process started by ``Child``: get SIGKILL when the parent dies. A parent that died
    before the request took effect is caught by the pid check, and we exit at once."""
    parent = os.environ.pop(PARENT_ENV, '')
    if not parent.isdigit():
        return
    _LIBC.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != int(parent):
        os._exit(1)


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
            env = dict(self.env, **{PARENT_ENV: str(os.getpid())})
            self.proc = subprocess.Popen(args, env=env, stdin=subprocess.DEVNULL, stdout=handle,
                                         stderr=subprocess.STDOUT, start_new_session=True)
        self.starts += 1
        self.started_at = time.monotonic()
        log.info('started %s (pid %d)', self.name, self.proc.pid)

    def exit_code(self) -> int | None:
        """The exit code (negative: killed by that signal) once the process has exited, else
        None; the process is not reaped (see the module docstring)."""
        if self.proc is None or self.proc.returncode is not None:
            return None if self.proc is None else self.proc.returncode
        try:
            info = os.waitid(os.P_PID, self.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:  # reaped elsewhere
            return self.proc.poll()
        if info is None:
            return None
        killed = info.si_code in (os.CLD_KILLED, os.CLD_DUMPED)
        return -info.si_status if killed else info.si_status

    def alive(self) -> bool:
        return self.proc is not None and self.exit_code() is None

    def _signal_group(self, sig: int) -> None:
        if self.proc.returncode is not None:  # reaped: the group id may belong to others now
            return
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def stop(self, grace_s: float = _STOP_GRACE_S) -> int | None:
        """SIGINT to the group, SIGKILL after ``grace_s``; the group's leftovers are killed
        before the leader is reaped."""
        if self.proc is None:
            return None
        if self.alive():
            self._signal_group(signal.SIGINT)
            deadline = time.monotonic() + grace_s
            while self.alive() and time.monotonic() < deadline:
                time.sleep(0.05)
            if self.alive():
                log.warning('%s ignored SIGINT for %.0f s: SIGKILL', self.name, grace_s)
        self._signal_group(signal.SIGKILL)  # e.g. a planning worker left behind
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


__all__ = ['Child', 'die_with_parent', 'node_command', 'node_name', 'start_node', 'stop']
