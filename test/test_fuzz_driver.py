"""The ``make fuzz`` driver itself: its watchdog pool tells hangs and deaths from answers, its
classification follows the documented rules, and a small run of every file family passes.

This module is also the pool's target in the first test (``setup`` and ``run`` below).
"""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import REPO
from fuzz.classify import classify_exception
from fuzz.pool import run_pool

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def setup(context):
    return context


def run(state, job):
    """A pool target whose jobs say what to do: answer, hang, die, or raise a bug."""
    kind, _ = job
    if kind == 'hang':
        time.sleep(600)
    elif kind == 'exit':
        os._exit(3)
    elif kind == 'segv':
        os.kill(os.getpid(), signal.SIGSEGV)
    elif kind == 'bug':
        raise AttributeError('no such thing')
    return 'ok', kind


def test_pool_tells_hangs_and_deaths_from_answers():
    jobs = [('ok', 0), ('hang', 1), ('ok', 2), ('exit', 3), ('segv', 4), ('bug', 5), ('ok', 6)]
    seen = {}
    t0 = time.monotonic()
    run_pool(jobs, 'test_fuzz_driver', {}, workers=2, timeout_s=3.0,
             record=lambda job, category, detail, s: seen.setdefault(job, (category, detail)))
    assert time.monotonic() - t0 < 120
    assert {job: c for job, (c, _) in seen.items()} == {
        ('ok', 0): 'ok', ('hang', 1): 'hang', ('ok', 2): 'ok', ('exit', 3): 'crash',
        ('segv', 4): 'crash', ('bug', 5): 'crash', ('ok', 6): 'ok'}
    assert 'exit code 3' in seen[('exit', 3)][1]
    assert f'exit code -{signal.SIGSEGV.value}' in seen[('segv', 4)][1]
    assert 'AttributeError' in seen[('bug', 5)][1]


def test_classification():
    from advocc_ros.model.pose import SceneError
    names = ('/tmp/x/input.yaml', 'input.yaml')
    doc = (SceneError,)
    assert classify_exception(SceneError('/tmp/x/input.yaml: objects[0].size: expected 3 '
                                         'numbers'), doc, names) == 'clear_error'
    assert classify_exception(SceneError('/tmp/x/input.yaml'), doc, names) == 'unclear_error'
    assert classify_exception(SceneError('bad value somewhere in it'), doc, names) == \
        'unclear_error'
    assert classify_exception(KeyError('x'), doc, names) == 'unclear_error'
    assert classify_exception(AttributeError('x'), doc, names) == 'crash'
    assert classify_exception(RecursionError(), doc, names) == 'crash'


def test_small_run_of_every_file_family(tmp_path):
    """56 inputs through the real driver: counts add up, the report is written, exit 0."""
    families = 'scene_yaml,mbm_scene,mbm_request,obstacles,heatmap,cloud_ply,cloud_pcd'
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO), str(REPO / 'test'), os.environ.get('PYTHONPATH', '')]))
    out = subprocess.run([sys.executable, '-m', 'fuzz', '--inputs', '56', '--families', families,
                          '--out', str(tmp_path), '--seed', '7'], env=env, cwd=REPO,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    report = json.loads((tmp_path / 'report.json').read_text())
    assert report['inputs'] == 56 and not report['failing']
    assert set(report['counts']) == set(families.split(','))
    for family, counts in report['counts'].items():
        assert sum(counts.values()) == report['planned'][family], family
    assert 'total' in out.stdout
