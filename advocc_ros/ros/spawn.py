"""Stopping child processes politely: the one way every advocc command does it."""

from __future__ import annotations

import signal
import subprocess


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
