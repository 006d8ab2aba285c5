"""Node processes: dying with the parent without a preexec_fn, and a process group that is only
signalled while its leader is unreaped."""

import os
import subprocess
import sys
import time

import pytest

from advocc_ros.ros.spawn import PARENT_ENV, Child
from conftest import REPO

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

_PROBE = 'from advocc_ros.ros.spawn import die_with_parent; die_with_parent(); print("alive")'


def _probe(parent: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), **{PARENT_ENV: parent})
    return subprocess.run([sys.executable, '-c', _PROBE], env=env, capture_output=True,
                          text=True, timeout=60)


def test_a_child_whose_parent_is_already_gone_exits_at_once():
    ok = _probe(str(os.getpid()))
    assert ok.returncode == 0 and ok.stdout.strip() == 'alive', ok.stderr
    orphan = _probe('1')  # not our parent: as if the real one died before prctl
    assert orphan.returncode == 1 and orphan.stdout == '', orphan.stderr


def _state(pid: int) -> str | None:
    try:
        with open(f'/proc/{pid}/stat') as handle:
            return handle.read().rsplit(')', 1)[1].split()[0]
    except FileNotFoundError:
        return None


def test_an_exited_child_stays_unreaped_until_stopped(tmp_path, ros_env):
    """heatmap_server without a heatmap exits with code 1; its zombie keeps the group id ours
    until ``stop`` (which may still signal the group) reaps it."""
    child = Child('probe', 'heatmap_server', {}, dict(ros_env, PYTHONPATH=str(REPO)), tmp_path)
    child.start()
    deadline = time.monotonic() + 60
    while child.alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert child.exit_code() == 1, child.tail()
    assert _state(child.pid) == 'Z' and child.proc.returncode is None
    assert child.stop() == 1
    assert _state(child.pid) is None
    assert child.stop() == 1  # again: the reaped group is never signalled
    assert 'cannot start' in child.tail()
