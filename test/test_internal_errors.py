"""A crash is not a planner failure: planning workers that raise or die inside a plan request
give INTERNAL_ERROR in ``advocc evaluate --json``, counted apart, left out of PSR, with a warning.

The faults are real: ``ADVOCC_PLANNING_FAULT`` (honoured by the worker for diagnostics only)
makes it raise or SIGKILL itself mid-request, and one test SIGKILLs the worker from outside.
"""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def _evaluate_cmd(trials: int, *extra: str) -> list[str]:
    return [sys.executable, '-m', 'advocc_ros.cli', 'evaluate', '--scene', 'table_pick',
            '--trials', str(trials), '--workers', '1', '--json', *extra]


def _env(fault: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop('ADVOCC_PLANNING_FAULT', None)
    if fault:
        env['ADVOCC_PLANNING_FAULT'] = fault
    return env


def _evaluate(fault: str, trials: int = 6) -> tuple[dict, str]:
    proc = subprocess.run(_evaluate_cmd(trials), capture_output=True, text=True,
                          env=_env(fault), timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout), proc.stderr


def _check_psr_over_the_rest(result: dict, errors: int) -> None:
    records = result['records']
    assert result['trials'] == len(records) and result['internal_errors'] == errors
    measured = [r for r in records if r['status'] != 'INTERNAL_ERROR']
    assert len(measured) == len(records) - errors
    assert result['successes'] == sum(r['success'] for r in measured)
    assert result['psr'] == pytest.approx(result['successes'] / len(measured))
    assert sum(result['failures'].values()) == len(measured) - result['successes']


def test_a_worker_killed_mid_plan_is_an_internal_error_not_a_failure():
    result, stderr = _evaluate('kill:2')
    statuses = [r['status'] for r in result['records']]
    assert statuses[2] == 'INTERNAL_ERROR', statuses
    assert 'killed by SIGKILL' in result['records'][2]['message']
    assert not result['records'][2]['success']
    _check_psr_over_the_rest(result, errors=1)
    assert result['psr'] == 1.0  # table_pick is easy: every measured trial succeeds
    assert 'warning: 1 of 6 trials were internal errors' in stderr


def test_an_exception_inside_the_plan_request_is_an_internal_error():
    result, stderr = _evaluate('raise:1,4')
    bad = [r for r in result['records'] if r['status'] == 'INTERNAL_ERROR']
    assert [r['trial'] for r in bad] == [1, 4]
    assert all('fault injected by ADVOCC_PLANNING_FAULT' in r['message'] for r in bad)
    _check_psr_over_the_rest(result, errors=2)
    assert result['psr'] == 1.0
    assert 'warning: 2 of 6 trials were internal errors' in stderr


def test_a_malformed_fault_setting_is_a_clear_internal_error():
    result, _ = _evaluate('explode:x', trials=1)
    (rec,) = result['records']
    assert rec['status'] == 'INTERNAL_ERROR' and 'expected raise:SEED' in rec['message']
    assert result['psr'] is None and result['internal_errors'] == 1


def test_a_worker_sigkilled_from_outside_mid_plan():
    """The measured case: PRM* plans for its whole 2 s budget, the worker is killed 3 s in."""
    proc = subprocess.Popen(_evaluate_cmd(4, '--planner', 'prmstar', '--time', '2'),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(), cwd=REPO)
    try:
        worker = None
        deadline = time.monotonic() + 120
        while worker is None and time.monotonic() < deadline:
            out = subprocess.run(['pgrep', '-P', str(proc.pid), '-f', 'import worker_main'],
                                 capture_output=True, text=True).stdout.split()
            worker = int(out[0]) if out else None
            time.sleep(0.1)
        assert worker is not None, 'no planning worker started'
        time.sleep(3.0)
        os.kill(worker, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    result = json.loads(stdout)
    bad = [r for r in result['records'] if r['status'] == 'INTERNAL_ERROR']
    assert len(bad) == 1 and 'killed by SIGKILL' in bad[0]['message'], result['records']
    _check_psr_over_the_rest(result, errors=1)
    assert result['failures']['planning failed'] == 0
