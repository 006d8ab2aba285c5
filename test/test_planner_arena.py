"""Bench results in OMPL's benchmark format: the logs parse with OMPL's own script into the
same database we write, Planner Arena's loader reads that database, and its page draws it in
headless Chromium.

Planner Arena and OMPL 2's script live in their own venvs (``.venv-arena``, ``.venv-ompl2``;
``make test`` makes both). ``ADVOCC_ARENA_SCREENSHOT=FILE`` copies the page's screenshot to
FILE (docs/planner_arena.png is made this way).
"""

import json
import os
import pathlib
import shutil
import socket
import sqlite3
import subprocess
import time
import urllib.request

import pytest

from advocc_ros.bench.arena import STATUS, write_ompl_results
from advocc_ros.bench.protocol import BenchConfig, trial_key
from advocc_ros.evaluation.runner import evaluate_planner
from conftest import CHROMIUM, needs_chromium

REPO = pathlib.Path(__file__).resolve().parents[1]
ARENA_PYTHON = REPO / '.venv-arena' / 'bin' / 'python'
OMPL_STATISTICS = REPO / '.venv-ompl2' / 'bin' / 'ompl_benchmark_statistics'
PAGE_DRIVER = pathlib.Path(__file__).with_name('arena_page.py')
VICTIMS = ('rrtconnect', 'bkpiece1', 'aorrtc')
TRIALS = 3


def _needs(path: pathlib.Path, what: str) -> None:
    if not path.is_file():
        pytest.skip(f'{what} is not installed at {path} (make test creates it)')


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory, table_scene):
    """A bench-like run folder of real trials: RRTConnect, BKPIECE1, AORRTC on table_pick."""
    out = tmp_path_factory.mktemp('arena')
    records = []
    for victim in VICTIMS:
        row = evaluate_planner(table_scene, victim, TRIALS, 1.0, seed=0)
        for rec in row['records']:
            records.append(dict(rec, key=trial_key('table_pick', victim, 'none', 0, rec['trial']),
                                scene='table_pick', planner=victim, method='none', budget=0,
                                unix=time.time()))
    cfg = BenchConfig(scenes=('table_pick',), planners=VICTIMS, methods=('ours',), budgets=(1,),
                      trials=TRIALS, time_budget_s=1.0)
    files = write_ompl_results(out, records, cfg)
    assert set(files) == {'benchmark.db', 'ompl_logs/table_pick_none_M0.log'}
    return out, records


def _rows(db: pathlib.Path, sql: str) -> list:
    with sqlite3.connect(db) as conn:
        return conn.execute(sql).fetchall()


@pytest.mark.processes
def test_ompl_script_makes_the_same_database_from_our_logs(run_dir, tmp_path):
    _needs(OMPL_STATISTICS, "OMPL 2's ompl_benchmark_statistics")
    out, records = run_dir
    theirs = tmp_path / 'ompl.db'
    subprocess.run([str(OMPL_STATISTICS), '-d', str(theirs),
                    *map(str, sorted((out / 'ompl_logs').glob('*.log')))],
                   check=True, capture_output=True, timeout=60)
    ours = out / 'benchmark.db'
    for table in ('experiments', 'plannerConfigs', 'enums', 'runs', 'progress'):
        cols = [c[1] for c in _rows(ours, f'PRAGMA table_info({table})')]
        assert cols == [c[1] for c in _rows(theirs, f'PRAGMA table_info({table})')], table
    query = ('SELECT p.name, r.time, r.solved, r.status, r.solution_length, r.goal_found, '
             'r.goal_attempts, r.seed '
             'FROM runs r JOIN plannerConfigs p ON r.plannerid = p.id ORDER BY r.id')
    assert [tuple(map(str, row)) for row in _rows(ours, query)] == \
        [tuple(map(str, row)) for row in _rows(theirs, query)]
    assert _rows(ours, 'SELECT name, value, description FROM enums ORDER BY value') == \
        _rows(theirs, 'SELECT name, value, description FROM enums ORDER BY value')
    assert len(_rows(ours, 'SELECT * FROM runs')) == len(records)


@pytest.mark.processes
def test_planner_arena_loads_the_database(run_dir):
    _needs(ARENA_PYTHON, 'Planner Arena')
    out, records = run_dir
    script = ('import json, sys\n'
              'from plannerarena.database import load_database\n'
              'd = load_database(sys.argv[1])\n'
              'runs = d["runs"]\n'
              'print(json.dumps({"problems": d["problem_names"], "parameters": d["parameters"],'
              ' "attributes": d["attributes"], "runs": runs.height,'
              ' "planners": sorted(set(map(str, runs["planner"].to_list()))),'
              ' "solved": int(runs["solved"].sum()),'
              ' "lengths": int(runs["solution length"].is_not_null().sum()),'
              ' "status": d["enums"]["description"].to_list()}))\n')
    done = subprocess.run([str(ARENA_PYTHON), '-c', script, str(out / 'benchmark.db')],
                          check=True, capture_output=True, text=True, timeout=120)
    data = json.loads(done.stdout.strip().splitlines()[-1])
    assert data['problems'] == ['table_pick_none_M0']
    assert data['parameters'] == ['budget', 'method', 'scene']
    assert data['runs'] == len(records) == TRIALS * len(VICTIMS)
    assert data['planners'] == ['AORRTC', 'BKPIECE1', 'RRTConnect']  # geometric_ stripped
    assert data['solved'] == data['lengths'] == sum(r['success'] for r in records)
    assert {'time', 'solved', 'status', 'solution length', 'goal found',
            'goal attempts'} <= set(data['attributes'])
    assert data['status'] == list(STATUS)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.mark.processes
def test_planner_arena_page_draws_the_benchmark_in_chromium(run_dir, tmp_path):
    _needs(ARENA_PYTHON, 'Planner Arena')
    needs_chromium()
    out, _ = run_dir
    port = _free_port()
    env = dict(os.environ, DATABASE=str(out / 'benchmark.db'))
    for key in ('PYTHONPATH', 'PYTHONHOME', 'LD_LIBRARY_PATH', 'VIRTUAL_ENV'):
        env.pop(key, None)
    server = subprocess.Popen([str(ARENA_PYTHON), '-m', 'shiny', 'run', '--host', '127.0.0.1',
                               '--port', str(port), 'plannerarena.app:app'], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    url = f'http://127.0.0.1:{port}/'
    try:
        deadline = time.monotonic() + 45
        while True:
            try:
                with urllib.request.urlopen(url, timeout=2) as page:
                    assert 'Planner Arena' in page.read().decode()
                break
            except OSError:
                assert server.poll() is None, server.stderr.read().decode()[-2000:]
                assert time.monotonic() < deadline, 'Planner Arena did not start in 45 s'
                time.sleep(0.5)
        png = tmp_path / 'arena.png'
        shown = subprocess.run([str(ARENA_PYTHON), str(PAGE_DRIVER), CHROMIUM, url, str(png),
                                str(_free_port())], check=True, capture_output=True, text=True,
                               env=env, timeout=120)
        page = json.loads(shown.stdout.strip().splitlines()[-1])
    finally:
        server.terminate()
        server.wait(10)
    assert page['plot_width'] > 0, 'Planner Arena drew no plot of our database'
    for text in ('table_pick_none_M0', 'RRTConnect', 'AORRTC', 'budget', 'method', 'scene'):
        assert text in page['text'], text  # our experiment, victims and problem parameters
    assert png.is_file() and png.stat().st_size > 10_000
    if os.environ.get('ADVOCC_ARENA_SCREENSHOT'):
        shutil.copy(png, os.environ['ADVOCC_ARENA_SCREENSHOT'])
