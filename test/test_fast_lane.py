"""The fast lane's refusal of processes holds in pytest-xdist's workers, and the controller
still starts them: a test that starts a process unmarked fails, naming the mark."""

import os
import subprocess
import sys

import pytest

from conftest import FAST_LANE_ENV, REPO

pytestmark = pytest.mark.processes  # pytest runs in a child, with its workers

PROBE = '''
import subprocess
import sys


def test_in_process():
    assert sum(range(4)) == 6


def test_starts_a_process():
    subprocess.run([sys.executable, '-c', 'pass'], check=True)
'''


@pytest.mark.parametrize('workers', ['1', '0'])  # an xdist worker; none
def test_fast_lane_refuses_processes_in_every_test_process(tmp_path, workers):
    (tmp_path / 'conftest.py').write_text((REPO / 'test' / 'conftest.py').read_text())
    (tmp_path / 'test_probe.py').write_text(PROBE)
    env = dict(os.environ, **{FAST_LANE_ENV: '1'})
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), env.get('PYTHONPATH', '')])
    out = subprocess.run([sys.executable, '-m', 'pytest', '-c', str(REPO / 'setup.cfg'),
                          '--rootdir', str(tmp_path), '-p', 'no:cacheprovider', '-n', workers,
                          '--durations=0', str(tmp_path)], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=300)
    text = out.stdout + out.stderr
    assert out.returncode == 1, text
    assert '1 failed, 1 passed' in text, text
    assert 'this test starts a process: mark it @pytest.mark.processes' in text, text
