"""``advocc dataset build`` on real MotionBenchMaker problems (test/data/mbm_real): selection,
records and bad input in-process, then real builds as the CLI runs them, on an embedded Ray and
on a two-node Ray cluster of separate ``ray start`` processes; builds stopped by SIGINT and by
kill -9 and resumed with a larger ``--limit``; malformed problems, a worker the test stops
(SIGSTOP: a real hung worker) and one it kills (SIGKILL: a real worker death), found by the pid
their problem's log names. Tiny settings (one box, one RRTConnect trial of 1 s) keep each
problem to seconds; the problems folder holds copies of the same problem under several numbers,
so the witness cache these tests share serves them all."""

import csv
import hashlib
import json
import os
import pathlib
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tarfile
import time

import numpy as np
import pytest
from conftest import ctrl_c_as_in_a_terminal

from advocc_ros.kernels.loader import digest
from advocc_ros.dataset.problems import DatasetError, discover, seeded_order, select, split_of

REPO = pathlib.Path(__file__).resolve().parents[1]
REAL = REPO / 'test' / 'data' / 'mbm_real'
ADVOCC = [sys.executable, '-m', 'advocc_ros.cli']
RAY = str(pathlib.Path(sys.executable).with_name('ray'))
TINY = ['--task-option', 'exit_rays=0', '--task-option', 'corridor_routes=0',
        '--task-option', 'pocket_samples=256', '--budgets', '1', '--victims', 'rrtconnect',
        '--trials', '1', '--time', '1', '--escape-rays', '500', '--goal-form', 'joint']
"""One box, one RRTConnect trial of 1 s, the joint goal form (one data set in OUT): the
smallest build that runs every step. Without the data set's ``exit_rays`` and
``corridor_routes`` and with the attack's own ``pocket_samples`` (together 10-20 s a problem;
test_goal_forms tests them)."""
HEATMAP = ['--heatmap-samples', '1000']
"""A small robot-only heatmap, built by the first build and reused by the later ones."""


def _run(args, env=None, timeout=300) -> subprocess.CompletedProcess:
    env = dict(env or os.environ, PYTHONUNBUFFERED='1')
    return subprocess.run(ADVOCC + ['dataset', 'build'] + [str(a) for a in args], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=timeout)


def _records(out: pathlib.Path) -> dict:
    return {f'{p.parent.parent.name}/{p.parent.name}': json.loads(p.read_text())
            for p in sorted(out.glob('*/*/outcome.json'))}


def _build_record(out: pathlib.Path) -> dict:
    return json.loads((out / 'build.json').read_text())


def _snapshot(folder: pathlib.Path) -> dict:
    """Every file and folder under ``folder`` with its bytes' hash and its mtime."""
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest()
                                         if p.is_file() else None, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob('*'))}


@pytest.fixture(scope='module')
def problems(tmp_path_factory) -> pathlib.Path:
    """Real problems: box_panda 0001-0003 (copies of MotionBenchMaker's box problem 0001) and
    table_pick_panda 0001."""
    root = tmp_path_factory.mktemp('problems')
    for family, numbers in (('box_panda', (1, 2, 3)), ('table_pick_panda', (1,))):
        (root / family).mkdir()
        for n in numbers:
            for kind in ('scene', 'request'):
                shutil.copy(REAL / family / f'{kind}0001.yaml',
                            root / family / f'{kind}{n:04d}.yaml')
    return root


# --------------------------------------------------------------------------------------------
# Selection, records and bad input (no process)

def test_a_larger_limit_selects_a_superset_in_a_seeded_order(tmp_path):
    for family in ('box_panda', 'cage_panda'):
        (tmp_path / family).mkdir()
        for i in (1, 2, 39, 40, 41, 42, 77, 100):
            (tmp_path / family / f'scene{i:04d}.yaml').write_text('{}')
    problems = discover(tmp_path)
    assert len(problems) == 16 and [split_of(i) for i in (1, 40, 41, 100)] == [
        'train', 'train', 'test', 'test']
    assert {p.index for p in select(problems, 'train')} == {1, 2, 39, 40}
    for seed in range(6):
        chosen = [select(problems, 'test', limit=n, seed=seed) for n in (1, 2, 3, 4, 5)]
        for smaller, larger in zip(chosen, chosen[1:]):
            assert set(smaller) <= set(larger), (seed, smaller, larger)  # a resume nests
        assert len(chosen[0]) == 2 and len(chosen[3]) == len(chosen[4]) == 8
        assert all(p.split == 'test' for p in chosen[4])
    draws = {tuple(p.key for p in select(problems, 'test', limit=2, seed=s)) for s in range(8)}
    assert len(draws) > 1  # the seed decides
    # A problem's place depends on the seed, its family and number only: one family's choice
    # is the same alone, and a folder with fewer problems keeps the order of the rest.
    test = select(problems, 'test', limit=2, seed=3)
    alone = select(discover(tmp_path, ['cage']), 'test', limit=2, seed=3)
    assert alone == [p for p in test if p.family == 'cage_panda']
    whole = seeded_order([p for p in problems if p.family == 'box_panda'], seed=3)
    assert seeded_order(whole[::2], seed=3) == whole[::2]
    # A build takes the families in turn: stopped part-way, it has some of each.
    from advocc_ros.dataset.driver import interleaved

    train = select(problems, 'train')
    order = interleaved(test + [p for p in train if p.family == 'box_panda'])
    assert [p.family[:3] for p in order] == ['box', 'cag'] * 2 + ['box'] * 4
    assert interleaved([]) == []


def test_the_limit_counts_the_problems_the_goal_form_poses(tmp_path):
    """MotionBenchMaker's cage 0001 holds its fingers at 0.065 m; clipped to the URDF's 0.04
    they close on the cube at the joint goal, so the joint form cannot pose it (the region form
    can). ``--limit N`` takes a family's seeded order up to its N-th posable problem: the
    refused ones before it are selected (their jobs say why), and a larger N still nests."""
    from advocc_ros.dataset.driver import posable_in
    from advocc_ros.dataset.job import BuildConfig

    (tmp_path / 'cage_panda').mkdir()
    for n, source in ((1, 'cage_panda'), (2, 'box_panda'), (3, 'box_panda'), (4, 'cage_panda')):
        for kind in ('scene', 'request'):
            shutil.copy(REAL / source / f'{kind}0001.yaml',
                        tmp_path / 'cage_panda' / f'{kind}{n:04d}.yaml')
    problems = discover(tmp_path)
    joint, region = (posable_in(BuildConfig(goal_form=f)) for f in ('joint', 'region'))
    assert [joint(p) for p in problems] == [False, True, True, False]
    assert all(region(p) for p in problems)
    for seed in range(4):
        order = seeded_order(problems, seed)
        for n in (1, 2):
            nth = [i for i, p in enumerate(order) if p.index in (2, 3)][n - 1]
            assert select(problems, limit=n, seed=seed, posable=joint) == order[:nth + 1]
            assert select(problems, limit=n, seed=seed, posable=region) == order[:n]
        assert select(problems, limit=3, seed=seed, posable=joint) == order  # short of 3


def test_bad_input_is_a_clear_error(tmp_path, capsys):
    from advocc_ros.cli import main

    with pytest.raises(DatasetError, match='no such problems folder'):
        discover(tmp_path / 'missing')
    with pytest.raises(DatasetError, match='no family folders'):
        discover(tmp_path)
    with pytest.raises(DatasetError, match="unknown family 'shelf'.*box_panda"):
        discover(REAL, ['box', 'shelf'])
    with pytest.raises(DatasetError, match='--split'):
        select(discover(REAL), 'validation')
    with pytest.raises(DatasetError, match='--limit'):
        select(discover(REAL), 'train', limit=0)
    out = tmp_path / 'out'
    for args, message in [
            (['--problems', tmp_path / 'nowhere'], 'no such problems folder'),
            (['--problems', REAL, '--families', 'shelf'], 'unknown family'),
            (['--problems', REAL, '--victims', 'rrtconnect,nosuch'], 'unknown'),
            (['--problems', REAL, '--budgets', '5,x'], 'comma-separated integers'),
            (['--problems', REAL, '--budgets', '0'], 'each must be in'),
            (['--problems', REAL, '--trials', '0'], '--trials'),
            (['--problems', REAL, '--escape-rays', '-1'], '--escape-rays must be in'),
            (['--problems', REAL, '--problem-timeout', '0'], '--problem-timeout > 0'),
            (['--problems', REAL, '--cpus-per-problem', '4096'], 'this process may use'),
            (['--problems', REAL, '--split', 'test'], 'no problems in split')]:
        assert main(['dataset', 'build', '--out', str(out)] + [str(a) for a in args]) == 2
        assert message in capsys.readouterr().err
    assert not out.exists()  # refused before anything is written
    with pytest.raises(SystemExit):
        main(['dataset', 'build', '--problems', str(REAL), '--out', str(out), '--split', 'x'])


def test_threads_are_capped_by_the_environment_or_the_affinity(monkeypatch):
    from advocc_ros.limits import THREADS_ENV, worker_threads

    monkeypatch.setenv(THREADS_ENV, '3')
    assert worker_threads() == 3
    for bad in ('0', '-2', 'two', '1.5'):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(ValueError, match=THREADS_ENV):
            worker_threads()
    monkeypatch.delenv(THREADS_ENV)
    assert worker_threads() == len(os.sched_getaffinity(0))
    from advocc_ros.dataset.threads import task_threads

    assert [task_threads(c) for c in (0.5, 1, 2, 3.5)] == [1, 1, 2, 3]


def test_ray_failures_are_recorded_as_what_they_are():
    import ray.exceptions as rx

    from advocc_ros.dataset.driver import classify

    cases = [(rx.OutOfMemoryError('Task was killed due to the node running low on memory.'),
              'memory', 'memory monitor'),
             (rx.TaskCancelledError(), 'cancelled', 'cancelled outside this build'),
             (rx.WorkerCrashedError(), 'crashed', 'died 3 time(s)'),
             (rx.NodeDiedError('node 1 died'), 'crashed', 'node 1 died'),
             (rx.RayTaskError('run_problem', 'Traceback ...',
                              TypeError("cannot pickle '_thread.lock' object")),
              'error', 'did not serialise (TypeError: cannot pickle'),
             (rx.RaySystemError('the object store is gone'), 'error',
              'RaySystemError: System error: the object store is gone')]
    for exc, outcome, words in cases:
        got = classify(exc, max_retries=2)
        assert got[0] == outcome and words in got[1], (exc, got)


def test_a_version_1_build_record_reads_as_its_first_run(tmp_path):
    """The published splits' ``build.json`` (version 1: one run, its heatmap named by path)
    reads as a version 2 record with that run as its first entry; the heatmap becomes its
    content's hash when the file is there, and a resume that cannot compare says why."""
    from advocc_ros.dataset import store
    from advocc_ros.dataset.heatmaps import file_sha256

    with tarfile.open(REPO / 'docs/results/mbm_dataset_train/hard_problems.tar.xz') as tar:
        published = json.load(tar.extractfile('./build.json'))
    assert published['version'] == 1 and 'file' in published['settings']['heatmap']
    heatmap = tmp_path / 'robot.npz'
    heatmap.write_bytes(b'heatmap bytes')
    for path, expected in ((heatmap, {'sha256': file_sha256(heatmap)}),
                           (tmp_path / 'gone.npz', {'file': str(tmp_path / 'gone.npz')})):
        old = json.loads(json.dumps(published))
        old['settings']['heatmap'] = {'file': str(path)}
        out = tmp_path / path.stem
        out.mkdir()
        store.write_json(out / 'build.json', old)
        record = store.read_build(out)
        assert record['version'] == 2 and len(record['runs']) == 1
        assert record['settings']['heatmap'] == expected
        run = record['runs'][0]
        assert run['selection'] == published['selection'] and run['status'] == 'finished'
        assert run['migrated'] == {'from_version': 1, 'settings': old['settings']}
    with pytest.raises(DatasetError, match='no longer there to compare'):
        store.check_settings(tmp_path / 'gone', dict(record['settings'], heatmap={'sha256': 'x'}))
    (tmp_path / 'gone' / 'build.json').write_text('{"format": "other"}')
    with pytest.raises(DatasetError, match='not a build record'):
        store.read_build(tmp_path / 'gone')


def test_the_summary_counts_the_witnesses_each_victims_checker_accepts(tmp_path):
    """Per budget and family, of the evaluated attacks' witnesses: how many MPlib's own check
    was asked about and how many it accepts (a witness a victim's checker calls blocked is no
    solution for that victim)."""
    from advocc_ros.dataset import store, summary

    keys = ['box_panda/0001', 'box_panda/0002', 'box_panda/0003']
    store.write_json(tmp_path / 'build.json', {
        'format': store.BUILD_FORMAT, 'version': store.BUILD_VERSION,
        'settings': {'build': {'budgets': [10], 'victims': ['mplib'], 'goal_form': 'joint'}},
        'runs': [{'selection': {'problems': keys}}]})
    for key, accepted in zip(keys, (True, False, None)):
        family, number = key.split('/')
        (tmp_path / key).mkdir(parents=True)
        store.write_json(tmp_path / key / 'outcome.json', {
            'family': family, 'problem': number, 'split': 'train', 'outcome': 'built'})
        checks = {} if accepted is None else {'mplib': {'accepted': accepted}}
        store.write_json(tmp_path / key / 'hardness.json', {
            'unattacked': {'mplib': {'psr': 1.0}},
            'attacks': {'10': {'all_victims_psr_le_20': accepted is not False,
                               'witness_checks': checks, 'victims': {'mplib': {'psr': 0.1}}}}})
    made = summary.summarise(tmp_path)
    pooled = next(g for g in made['groups'] if g['family'] == 'all')
    assert pooled['budgets']['10']['witness_checks'] == {'mplib': {'checked': 2, 'accepted': 1}}
    assert '| M=10: witness accepted by mplib |' in summary.markdown(made)
    assert '| 1 of 2 |' in summary.markdown(made)


def test_the_summary_gives_each_victims_share_of_problems_held(tmp_path):
    """Per victim and budget: the share of problems at PSR <= 20 %, and its PSR given goals
    (trials whose goal search found none left out) with the share at <= 50 %: the bar for a
    victim handed valid goals."""
    from advocc_ros.dataset import store, summary

    keys = ['box_panda/0001', 'box_panda/0002', 'box_panda/0003', 'cage_panda/0001']
    store.write_json(tmp_path / 'build.json', {
        'format': store.BUILD_FORMAT, 'version': store.BUILD_VERSION,
        'settings': {'build': {'budgets': [10], 'victims': ['mplib'], 'goal_form': 'region'}},
        'runs': [{'selection': {'problems': keys}}]})
    cells = [(0.1, 0.1), (0.3, 0.5), (0.4, 0.8), (0.2, None)]
    for key, (psr, given) in zip(keys, cells):
        family, number = key.split('/')
        (tmp_path / key).mkdir(parents=True)
        store.write_json(tmp_path / key / 'outcome.json', {
            'family': family, 'problem': number, 'split': 'test', 'outcome': 'built'})
        store.write_json(tmp_path / key / 'hardness.json', {
            'unattacked': {'mplib': {'psr': 0.9, 'psr_given_goals': 1.0}},
            'attacks': {'10': {'all_victims_psr_le_20': psr <= 0.2, 'victims': {
                'mplib': {'psr': psr, 'psr_given_goals': given}}}}})
    made = summary.summarise(tmp_path)
    pooled = next(g for g in made['groups'] if g['family'] == 'all')
    mplib = pooled['budgets']['10']['victims']['mplib']
    assert mplib['psr_le_20'] == 0.5
    assert mplib['psr_given_goals_le_50'] == 2 / 3
    assert mplib['mean_psr_given_goals'] == pytest.approx(1.4 / 3)
    assert pooled['unattacked']['mplib'] == {'mean_psr': 0.9, 'mean_psr_given_goals': 1.0}
    box = next(g for g in made['groups'] if g['family'] == 'box_panda')
    assert box['budgets']['10']['victims']['mplib']['psr_given_goals_le_50'] == 2 / 3


def test_records_name_their_machines_speed_and_speeds_apart_do_not_pool(tmp_path, capsys):
    """The machine speed probe (validity checks/s on the shipped table_pick scene, also
    ``advocc perf speed``) is a rate this machine reaches; built records 2x apart in speed are
    flagged as not pooling in the summary, and a run on a machine more than ``SPEED_SPREAD``
    off the folder's records is warned (its probe a median of several); machines (Ray nodes)
    and probes within it, or records without a speed, are not."""
    from advocc_ros.cli import main
    from advocc_ros.dataset import store, summary
    from advocc_ros.dataset.machines import probe, speed_note
    from advocc_ros.evaluation.provenance import SPEED_SPREAD, speed

    here = speed()  # how far from the machine's median depends on its load: not asserted
    assert 0 < here < 10 ** 8 and 0 < probe(3) < 10 ** 8
    assert main(['perf', 'speed', '--json']) == 0
    reported = json.loads(capsys.readouterr().out)
    assert reported['scene'] == 'table_pick' and reported['pools_within'] == SPEED_SPREAD
    assert reported['made']['host'] and 'commit' in reported['made']
    assert 0 < reported['speed_checks_per_s'] < 10 ** 8
    keys = ['box_panda/0001', 'box_panda/0002', 'box_panda/0003']
    store.write_json(tmp_path / 'build.json', {
        'format': store.BUILD_FORMAT, 'version': store.BUILD_VERSION,
        'settings': {'build': {'budgets': [10], 'victims': ['mplib'], 'goal_form': 'joint'}},
        'runs': [{'selection': {'problems': keys}}]})

    def made(*speeds):  # (Ray node, speed) per problem
        for key, (node, value) in zip(keys, speeds):
            family, number = key.split('/')
            (tmp_path / key).mkdir(parents=True, exist_ok=True)
            store.write_json(tmp_path / key / 'outcome.json', {
                'family': family, 'problem': number, 'split': 'train', 'outcome': 'built',
                'provenance': {'host': 'vm', 'node': node, 'speed_checks_per_s': value}})
        return summary.summarise(tmp_path)['made']['speed_of_built_problems']

    assert made(('a', here), ('b', 2 * here), ('b', None)) == {
        'known': 2, 'unknown': 1, 'min': here, 'median': 1.5 * here, 'max': 2 * here,
        'machines': {'a': here, 'b': 2 * here}, 'spread': 2.0, 'pooled': False}
    assert "the machines' medians 2.00x apart" in summary.markdown(summary.summarise(tmp_path))
    assert str(2 * here) in summary.csv_text(summary.table_rows(tmp_path))
    records = [r for r, _ in store.records(tmp_path, keys)]
    assert 'faster' in speed_note(records[:1], 2.5 * here, 5)
    note = speed_note(records, 0.5 * here, 5)  # median 1.5 x here: 3x slower
    assert '3.00x slower' in note and 'a 5 s budget buys that much less planning' in note
    assert speed_note(records[:1], here * SPEED_SPREAD * 0.99, 5) is None
    assert '1.60x slower' in speed_note(records[:1], here / 1.6, 5)  # apart enough not to pool
    assert speed_note(records[2:], 10 * here, 5) is None  # no speed recorded
    # One machine's probes drift: it is judged by their median.
    assert made(('a', here), ('a', 2 * here), ('b', 1.2 * here))['pooled'] is True
    assert made(('a', here), ('a', 2 * here), ('a', here))['machines'] == {'a': here}
    assert made(('a', None), ('b', None), ('a', None))['pooled'] is None  # older records


@pytest.mark.processes  # the child writes to the captured descriptors; git names the commit
def test_a_tasks_output_and_logs_go_to_its_log(tmp_path, capfd):
    import logging

    from advocc_ros.dataset.job import problem_input, run_problem, task_log
    from advocc_ros.dataset.job import BuildConfig

    with task_log({'path': str(tmp_path / 'x.log'), 'node': None}, 'a/0001') as got:
        subprocess.run(['echo', 'a child process writes this'], check=True)
        logging.getLogger('advocc_ros.test').info('an INFO record')
        print('and this process', flush=True)
    assert not (tmp_path / 'x.log').exists()  # not on the driver's node: the text comes back
    for words in ('--- a/0001: ', 'a child process writes this', 'INFO advocc_ros.test: an '
                  'INFO record', 'and this process', '--- a/0001: ended'):
        assert words in got['text']
    print('after the task', flush=True)
    assert capfd.readouterr().out == 'after the task\n'  # the descriptors are restored
    # A problem that does not load: refused, with its provenance and its log.
    problem = discover(REAL, ['box'])[0]
    data = dict(problem_input(problem), scene=b'world: [unclosed\n')
    result = run_problem(data, None, BuildConfig(), {'path': str(tmp_path / 'y.log'),
                                                     'node': None})
    record = result['record']
    assert record['outcome'] == 'refused' and 'malformed problem' in record['reason']
    made = record['provenance']
    assert re.fullmatch('[0-9a-f]{40}', made['commit']) and isinstance(made['dirty'], bool)
    assert made['host'] == socket.gethostname() and made['cpus'] is None
    assert made['threads'] >= 1 and len(made['load']) == 3 and made['versions']['numpy']
    assert made['started'] <= made['finished']
    assert 'box_panda/0001: refused malformed problem' in result['log']


@pytest.mark.processes  # build.json records the checkout's commit (git)
def test_a_heatmap_that_does_not_fit_or_a_locked_folder_is_refused_before_any_work(
        tmp_path, heatmap_file, other_heatmap):
    from advocc_ros.dataset.driver import RunConfig, Selection, build
    from advocc_ros.dataset.job import BuildConfig

    selection = Selection(str(REAL), ('box',))
    with pytest.raises(DatasetError, match='scene-conditioned heatmap fits one scene'):
        build(selection, tmp_path / 'a', BuildConfig(), RunConfig(heatmap_file=str(
            heatmap_file)))
    with pytest.raises(DatasetError, match='not the robot of box_panda/0001'):
        build(selection, tmp_path / 'b', BuildConfig(), RunConfig(heatmap_file=str(
            other_heatmap)))
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()
    # A folder another build holds is refused before anything is written to it.
    from advocc_ros.dataset import store

    out = tmp_path / 'c'
    out.mkdir()
    with store.locked(out):
        with pytest.raises(DatasetError, match='another build is running on this folder'):
            build(selection, out, BuildConfig(), RunConfig())
    assert [p.name for p in out.iterdir()] == [store.LOCK_FILE]


@pytest.fixture(scope='module')
def other_heatmap(tmp_path_factory):
    """A robot-only heatmap of another robot (the shipped box scene's Panda, whose fingers
    are not locked as MotionBenchMaker's problems lock them)."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    from advocc_ros.model.scene import load_scene

    path = tmp_path_factory.mktemp('other_heatmap') / 'srdf_fingers.npz'
    save_heatmap(build_heatmap(load_scene(REPO / 'config' / 'scenes' / 'box.yaml'),
                               HeatmapConfig(samples=200, robot_only=True)), path)
    return path


# --------------------------------------------------------------------------------------------
# Builds (each starts Ray and planner processes)

@pytest.fixture(scope='module')
def built(tmp_path_factory, problems):
    """A fresh build of two problems per family on the embedded Ray, its robot-only heatmap
    built too: the output folder and the CLI's run."""
    out = tmp_path_factory.mktemp('dataset') / 'out'
    t0 = time.monotonic()
    run = _run(['--problems', problems, '--out', out, '--limit', 2] + HEATMAP + TINY)
    print(f'embedded build: {time.monotonic() - t0:.1f} s wall')
    return out, run


@pytest.fixture(scope='module')
def robot_heatmap(built) -> pathlib.Path:
    """The robot-only heatmap the first build made (a file of its own)."""
    out, _ = built
    return next((out / 'heatmaps').glob('robot-*.npz'))


def _selection(problems: pathlib.Path, limit: int) -> list[str]:
    return [p.key for p in select(discover(problems), 'all', limit, 0)]


@pytest.mark.processes
def test_build_on_embedded_ray(built, problems):
    from advocc_ros.formats.mbm_export import load_trajectory
    from advocc_ros.formats.mbm_scene import load_any_scene

    out, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    assert '3 built' in run.stdout and 'done=3, left=0' in run.stderr
    records = _records(out)
    assert sorted(records) == sorted(_selection(problems, 2))  # 2 of box's 3, table_pick's 1
    commit = subprocess.run(['git', '-C', str(REPO), 'rev-parse', 'HEAD'], capture_output=True,
                            text=True, check=True).stdout.strip()
    for key, record in records.items():
        assert record['outcome'] == 'built' and record['split'] == 'train', record
        made = record['provenance']
        assert made['commit'] == commit and isinstance(made['dirty'], bool)
        assert made['cpus'] == 2 and made['threads'] == 2
        assert made['versions']['kernels'] == digest() and made['versions']['kernels_compiler']
        assert made['victims_cpus_alone'] is True and made['host'] and made['cpu']
        assert made['started'] <= made['finished'] and len(made['load_end']) == 3
        assert made['speed_checks_per_s'] > 1000  # measured by the job, on its CPUs
        folder = out / key
        hardness = json.loads((folder / 'hardness.json').read_text())
        attack = hardness['attacks']['1']
        assert attack['certificate'] == 'certified' and attack['boxes'] == 1
        assert attack['witness_candidates'] >= 1 and 'goal_exits' not in attack  # exit_rays=0
        cell = attack['victims']['rrtconnect']
        assert cell['trials'] == 1 and 'first_solution_median_s' in cell and 'pt_ratio' in cell
        assert hardness['unattacked']['rrtconnect']['trials'] == 1
        family, number = key.split('/')
        original = load_any_scene(problems / family / f'scene{number}.yaml',
                                  problems / family / f'request{number}.yaml')
        exported = load_any_scene(folder / 'm1' / f'scene{number}.yaml',
                                  folder / 'm1' / f'request{number}.yaml')
        assert len(exported.objects) == len(original.objects) + 1
        names, waypoints = load_trajectory(folder / 'm1' / f'trajectory{number}.yaml')
        assert len(names) == 7 and len(waypoints) == attack['witness_waypoints']
        log = (out / 'logs' / f'{key}.log').read_text()
        assert f'--- {key}: ' in log and 'attack at M=1' in log and f'{key}: built' in log
    assert len(list((out / 'heatmaps').glob('robot-*.npz'))) == 1  # one robot, one heatmap
    build = _build_record(out)
    assert build['version'] == 2 and build['settings']['build']['budgets'] == [1]
    [entry] = build['runs']
    assert entry['status'] == 'finished' and entry['counts'] == {'built': 3}
    assert entry['provenance']['commit'] == commit and entry['provenance']['versions']['ray']
    assert entry['selection']['problems'] == _selection(problems, 2)
    assert entry['timing']['victims_cpus_alone'] is True
    assert entry['timing']['cpus_per_problem'] == 2
    assert entry['run']['problem_timeout_s'] == 3600 and entry['cluster']['nodes'] == 1
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['made']['timing_of_built_problems'] == {
        'victims_cpus_alone': 3, 'shared': 0, 'unknown': 0}
    assert entry['speed_checks_per_s'] > 1000  # the driver's machine, as the run starts
    assert summary['made']['speed_of_built_problems']['known'] == 3
    pooled = next(g for g in summary['groups'] if g['family'] == 'all')
    assert pooled['split'] == 'train' and pooled['problems'] == 3
    assert pooled['shares']['built'] == 1.0 and pooled['budgets']['1']['evaluated'] == 3
    text = (out / 'summary.md').read_text()
    assert '| box_panda | 2 |' in text and f'`{commit[:12]}' in text and 'alone' in text
    assert 'Machine speed (validity checks/s before the work)' in text
    assert (out / 'summary.png').read_bytes()[:4] == b'\x89PNG'


@pytest.mark.processes  # the `built` fixture runs a build
def test_every_table_row_names_its_making(built):
    """problems.csv: per problem, the unattacked row and the attacked one, each with its
    problem's provenance."""
    out, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    records = _records(out)
    commit = records['table_pick_panda/0001']['provenance']['commit']
    rows = list(csv.DictReader((out / 'problems.csv').open()))
    assert [(r['family'], r['budget']) for r in rows] == [
        (k.split('/')[0], b) for k in sorted(records) for b in '01']
    for row in rows:
        made = records[f'{row["family"]}/{row["problem"]}']['provenance']
        assert row['commit'] == commit and row['host'] == made['host'] and row['cpus'] == '2.0'
        assert row['started'] == made['started'] and f'ray={made["versions"]["ray"]}' in \
            row['versions'] and float(row['load_start']) == made['load'][0]
    attacked = json.loads((out / rows[1]['family'] / rows[1]['problem'] / 'hardness.json')
                          .read_text())['attacks']['1']
    assert rows[1]['certificate'] == 'certified' and rows[1]['boxes'] == '1'
    assert float(rows[1]['psr']) == attacked['victims']['rrtconnect']['psr']
    escape = attacked['goal_escape']  # the joint goal's escape share, one box placed
    assert escape['rays'] == 500 and escape['step_rad'] == 0.01 and 0 <= escape['free'] <= 500
    assert float(rows[1]['goal_escape_p']) == escape['free'] / 500
    assert rows[0]['goal_escape_p'] == ''  # the unattacked row
    assert attacked['direct_motion'] == rows[1]['direct_motion'] == 'blocked'  # by the scene
    assert int(rows[1]['witness_waypoints']) == attacked['witness_waypoints'] > 2


@pytest.mark.processes  # the `built` fixture runs a build
def test_summary_rewrites_a_build_folders_summary(built, tmp_path, capsys):
    """``advocc dataset summary`` summarises the selection of the folder's last run, as far
    as it got; records outside the selection do not count; a folder without a build record is
    a clear error."""
    from advocc_ros.cli import main

    out, _ = built
    copy = tmp_path / 'copy'
    shutil.copytree(out, copy)
    shutil.rmtree(copy / 'table_pick_panda')  # as if stopped before that problem
    shutil.copytree(copy / 'box_panda' / '0001', copy / 'box_panda' / '0099')  # not selected
    for name in ('summary.json', 'summary.md', 'problems.csv'):
        (copy / name).unlink()
    assert main(['dataset', 'summary', str(copy)]) == 0
    assert '| box_panda | 2 |' in capsys.readouterr().out
    summary = json.loads((copy / 'summary.json').read_text())
    assert summary['problems'] == 2 and summary['selected'] == 3
    assert len((copy / 'problems.csv').read_text().splitlines()) == 5
    assert main(['dataset', 'summary', str(tmp_path / 'nowhere')]) == 2
    assert 'not a data set build folder' in capsys.readouterr().err


@pytest.mark.processes  # the `built` fixture runs a build; MPlib's checker is a worker
def test_check_asks_every_exported_witness_again_from_its_files(built, tmp_path, capsys):
    """``advocc dataset check``: each exported witness certified again on its exported scene
    and asked of MPlib's own collision check; a box put in one witness's way (in the scene
    file) is caught by both; an MPlib worker that dies and a damaged file are their rows' error,
    the others still checked (exit 1); a folder without problems or an unknown checker is a
    clear error."""
    import dataclasses

    from advocc_ros.cli import main
    from advocc_ros.formats.mbm_export import load_trajectory, planning_scene_data
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import make_box, save_yaml_atomic

    fresh, _ = built
    out = tmp_path / 'out'
    shutil.copytree(fresh, out, ignore=shutil.ignore_patterns('heatmaps', 'logs'))
    blocked = sorted(_records(out))[-1]
    family, number = blocked.split('/')
    folder = out / blocked / 'm1'
    scene = load_any_scene(folder / f'scene{number}.yaml', folder / f'request{number}.yaml')
    robot = load_robot(scene.robot)
    names, waypoints = load_trajectory(folder / f'trajectory{number}.yaml')
    middle = waypoints[len(waypoints) // 2]
    hand_m = robot.ee_pose(np.array([middle[names.index(j)] for j in robot.joint_names]))
    scene = dataclasses.replace(scene, objects=scene.objects + (
        make_box('in_the_way', hand_m.translation, (0.1, 0.1, 0.1)),))
    save_yaml_atomic(folder / f'scene{number}.yaml', planning_scene_data(scene, robot))

    assert main(['dataset', 'check', str(out)]) == 0
    assert '3 exported witnesses: 2 certified (coal), 2 accepted by MPlib' in \
        capsys.readouterr().out
    rows = {f'{r["family"]}/{r["problem"]}': r
            for r in csv.DictReader((out / 'witness_checks.csv').open())}
    assert sorted(rows) == sorted(_records(out))
    tally = json.loads((out / 'witness_checks.json').read_text())
    assert (tally['witnesses'], tally['certified'], tally['mplib_accepted']) == (3, 2, 2)
    assert tally['goal_forms'] == ['joint'] and tally['made']['commit'] == subprocess.run(
        ['git', '-C', str(REPO), 'rev-parse', 'HEAD'], capture_output=True, text=True,
        check=True).stdout.strip()
    assert [(g['family'], g['witnesses'], g['mplib_accepted']) for g in tally['groups']] == [
        (f, sum(k.startswith(f) for k in rows), sum(k.startswith(f) and k != blocked
                                                    for k in rows))
        for f in sorted({k.split('/')[0] for k in rows})]
    for key, row in rows.items():
        assert row['budget'] == '1' and row['goal_form'] == 'joint', row
        if key == blocked:
            assert row['certificate'] == 'refused' and 'in_the_way' in row['message'], row
            assert row['mplib_accepted'] == 'False' and int(row['mplib_colliding']) > 0, row
        else:
            assert row['certificate'] == 'certified' and float(row['min_clearance_mm']) > 0
            assert row['mplib_accepted'] == 'True' and row['mplib_colliding'] == '0', row
    assert main(['dataset', 'check', str(out), '--checkers', 'coal', '--csv',
                 str(tmp_path / 'coal.csv')]) == 0
    coal = list(csv.DictReader((tmp_path / 'coal.csv').open()))
    assert [r['certificate'] for r in coal] == [rows[k]['certificate'] for k in sorted(rows)]
    assert all(r['mplib_accepted'] == '' for r in coal)
    assert json.loads((tmp_path / 'coal.json').read_text())['mplib_accepted'] is None
    # An MPlib worker that dies (an interpreter that exits at once) is each row's MPlib error.
    with pytest.MonkeyPatch.context() as env:
        env.setenv('ADVOCC_MPLIB_PYTHON', shutil.which('false'))
        assert main(['dataset', 'check', str(out), '--csv', str(tmp_path / 'died.csv')]) == 1
    assert '3 exported witnesses: 2 certified (coal), 3 MPlib could not answer' in \
        capsys.readouterr().out
    died = list(csv.DictReader((tmp_path / 'died.csv').open()))
    assert [r['certificate'] for r in died] == [rows[k]['certificate'] for k in sorted(rows)]
    assert all('exited' in r['mplib_error'] and r['mplib_accepted'] == '' for r in died), died
    # A damaged file is its problem's row, not the end of the check.
    first, second = sorted(rows)[:2]
    (out / first / 'm1' / f'trajectory{first[-4:]}.yaml').write_text('joint_trajectory: [\n')
    (out / second / 'hardness.json').write_text('{"attacks": ')
    assert main(['dataset', 'check', str(out), '--checkers', 'coal', '--csv',
                 str(tmp_path / 'damaged.csv')]) == 1
    assert '3 exported witnesses: 0 certified (coal), 2 unreadable' in capsys.readouterr().out
    damaged = {f'{r["family"]}/{r["problem"]}': r
               for r in csv.DictReader((tmp_path / 'damaged.csv').open())}
    assert damaged[first]['certificate'] == 'unreadable', damaged[first]
    assert f'trajectory{first[-4:]}.yaml: malformed YAML' in damaged[first]['message']
    assert damaged[second]['certificate'] == 'unreadable' and damaged[second]['budget'] == '0'
    assert 'hardness.json: cannot be read' in damaged[second]['message']
    assert damaged[blocked]['certificate'] == 'refused'
    assert json.loads((tmp_path / 'damaged.json').read_text())['unreadable'] == 2
    assert main(['dataset', 'check', str(tmp_path / 'nowhere')]) == 2
    assert 'no problem of a data set build' in capsys.readouterr().err
    assert main(['dataset', 'check', str(out), '--checkers', 'coal,fcl']) == 2
    assert "unknown ['fcl']" in capsys.readouterr().err


@pytest.mark.processes
def test_refused_settings_leave_the_folder_as_it_was(built, problems, robot_heatmap,
                                                     other_heatmap, tmp_path):
    """A resume with nothing left starts no Ray (and adds its entry); other build settings,
    a heatmap file instead of the built one, another robot's and a missing one are refused
    and change nothing in the folder."""
    out, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    base = ['--problems', problems, '--limit', 2, '--out', out] + TINY
    again = _run(base + HEATMAP)
    assert again.returncode == 0 and 'nothing to do' in again.stdout, again.stderr[-3000:]
    assert 'Ray' not in again.stderr
    assert [r['status'] for r in _build_record(out)['runs']] == ['finished', 'finished']
    before = _snapshot(out)
    for args, words in [
            (TINY[:-2] + ['--time', '2'] + HEATMAP, 'other settings (build)'),
            (['--heatmap', robot_heatmap], 'other settings (heatmap)'),
            (['--heatmap', other_heatmap], 'other settings (heatmap)'),
            (['--heatmap', tmp_path / 'no_such.npz'], 'no_such.npz')]:
        refused = _run(base + args)
        assert refused.returncode == 2 and words in refused.stderr, (args, refused.stderr)
        assert _snapshot(out) == before, args


def _pids(log: pathlib.Path) -> list[int]:
    """The worker pids of the attempts a problem's log names, in order."""
    text = log.read_text() if log.exists() else ''
    return [int(pid) for pid in re.findall(r'^--- \S+: \S+ pid (\d+), ', text, re.M)]


def _started(proc: subprocess.Popen, log: pathlib.Path, timeout: float = 240) -> int:
    """The pid of the worker running the problem of ``log``, once its job has started."""
    _wait(proc, lambda: _pids(log), f'{log.name} started', timeout)
    return _pids(log)[0]


def _wait(proc: subprocess.Popen, condition, what: str, timeout: float = 240) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, f'the build ended before {what}'
        assert time.monotonic() < deadline, f'no {what} within {timeout} s'
        time.sleep(0.1)


def _gone(pid: int, timeout: float = 30) -> bool:
    """Whether every process the build ``pid`` started ends within ``timeout``."""
    deadline = time.monotonic() + timeout
    while _started_by(pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    return not _started_by(pid)


def _started_by(pid: int) -> list[int]:
    """The live processes whose SID (``setsid``) is ``pid``: a build started as the leader of
    its own, and all it started, its Ray workers too (they lead process groups of their
    own)."""
    found = []
    for stat in pathlib.Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == pid and fields[0] != 'Z':
            found.append(int(stat.parent.name))
    return found


class _Build:
    """A CLI build started with a SID of its own, output in files; on exit every process
    with that SID (the build, its Ray) is killed."""

    def __init__(self, args, folder: pathlib.Path, name: str):
        self.stdout, self.stderr = folder / f'{name}.out', folder / f'{name}.err'
        with open(self.stdout, 'w') as out, open(self.stderr, 'w') as err:
            self.proc = subprocess.Popen(
                ADVOCC + ['dataset', 'build'] + [str(a) for a in args], cwd=REPO,
                env=dict(os.environ, PYTHONUNBUFFERED='1'), stdout=out, stderr=err,
                start_new_session=True, preexec_fn=ctrl_c_as_in_a_terminal)

    def __enter__(self):
        return self

    def wait(self, timeout: float = 300) -> int:
        return self.proc.wait(timeout)

    def text(self) -> str:
        return self.stdout.read_text() + self.stderr.read_text()

    def __exit__(self, *exc):
        for pid in [self.proc.pid] + _started_by(self.proc.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.proc.wait(30)


def _results(out: pathlib.Path) -> dict:
    """What a build found, without what a clock or a machine decides (PSR and times of one
    1 s trial on a shared machine, provenance): the summary's counts per group and the
    table's rows up to the trials."""
    summary = json.loads((out / 'summary.json').read_text())
    groups = [{k: g[k] for k in ('family', 'split', 'problems', 'outcomes')}
              | {'evaluated': {b: c['evaluated'] for b, c in g['budgets'].items()}}
              for g in summary['groups']]
    keep = ('family', 'problem', 'split', 'outcome', 'budget', 'certificate', 'boxes',
            'victim', 'trials')
    rows = [{k: r[k] for k in keep} for r in csv.DictReader((out / 'problems.csv').open())]
    return {'problems': summary['problems'], 'selected': summary['selected'],
            'settings': summary['settings'], 'groups': groups, 'rows': rows}


@pytest.mark.processes
def test_builds_stopped_by_sigint_and_kill_or_a_killed_worker_resume_to_a_fresh_builds_summary(
        built, problems, tmp_path):
    """Ctrl-C during the first problem of --limit 1; kill -9 of the driver after the first
    problem of --limit 2; a resume with --limit 2 whose worker is killed (SIGKILL) once the
    second problem's job has started, and which Ray runs again: the same records and summary
    as the fresh build of --limit 2, and one build.json entry per run."""
    fresh, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    out = tmp_path / 'out'
    shutil.copytree(fresh / 'heatmaps', out / 'heatmaps')  # reused, as by any resume
    args = ['--problems', problems, '--out', out] + HEATMAP + TINY
    first = _selection(problems, 1)[0]
    with _Build(args + ['--limit', 1], tmp_path, 'sigint') as b:
        _started(b.proc, out / 'logs' / f'{first}.log')
        os.killpg(b.proc.pid, signal.SIGINT)  # Ctrl-C: the whole foreground group
        assert b.wait() == 130, b.text()[-3000:]
        assert 'interrupted' in b.text()
        assert _gone(b.proc.pid), _started_by(b.proc.pid)  # Ray stopped with it
    assert _records(out) == {}
    assert [r['status'] for r in _build_record(out)['runs']] == ['interrupted']
    with _Build(args + ['--limit', 2], tmp_path, 'kill') as b:
        _wait(b.proc, lambda: _records(out), 'first record')
        b.proc.kill()
        b.wait()
    assert list(_records(out)) == [first]
    second = _selection(problems, 2)[1]
    log = out / 'logs' / f'{second}.log'
    earlier = _pids(log)  # the killed driver's attempt, if it got that far
    with _Build(args + ['--limit', 2], tmp_path, 'resume') as b:
        _wait(b.proc, lambda: len(_pids(log)) > len(earlier), f'{second} started')
        killed = _pids(log)[-1]
        os.kill(killed, signal.SIGKILL)  # mid-problem: its job has started
        assert b.wait() == 0, b.text()[-3000:]
        assert '1 already finished' in b.text() and '2 built' in b.text()
    retried = _records(out)[second]['provenance']['pid']
    assert _pids(log) == earlier + [killed, retried] and retried != killed
    runs = _build_record(out)['runs']
    assert [r['status'] for r in runs] == ['interrupted', 'running', 'finished']
    assert [r['resumed'] for r in runs] == [0, 0, 1] and runs[2]['counts'] == {'built': 2}
    assert sorted(_records(out)) == sorted(_records(fresh)) == sorted(_selection(problems, 2))
    assert _results(out) == _results(fresh)


def test_a_ctrl_c_whose_interrupt_is_swallowed_is_remembered():
    """A KeyboardInterrupt caught by the code it was raised in (as a wait that runs signal
    handlers itself may do): the build's loop still sees the Ctrl-C; an inherited SIG_IGN (a
    background job's) stays."""
    from advocc_ros.dataset import driver

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with driver._ctrl_c_kept():
            assert not driver._SIGINT_SEEN.is_set()
            with pytest.raises(KeyboardInterrupt):  # raised as by Python's own handler...
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)
            assert driver._SIGINT_SEEN.is_set()  # ...and remembered
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with driver._ctrl_c_kept():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)


@pytest.mark.processes
def test_a_hung_problem_times_out_and_malformed_ones_are_refused(
        problems, robot_heatmap, tmp_path):
    """Box problem 0001 hangs (its worker stopped by SIGSTOP) and is cancelled at
    --problem-timeout; three malformed problems are refused; the build finishes."""
    folder = tmp_path / 'problems'
    shutil.copytree(problems, folder)
    box = folder / 'box_panda'
    text = (box / 'scene0001.yaml').read_text()
    assert 'type: box' in text
    (box / 'scene0002.yaml').write_text(text.replace('type: box', 'type: blob', 1))
    (box / 'request0003.yaml').unlink()
    (box / 'scene0004.yaml').write_text('world: [unclosed\n')
    shutil.copy(box / 'request0001.yaml', box / 'request0004.yaml')
    out = tmp_path / 'out'
    timeout = 20  # a Ray worker starts and takes the job within it on a loaded 2-core machine
    with _Build(['--problems', folder, '--families', 'box', '--out', out, '--heatmap',
                 robot_heatmap, '--cpus-per-problem', 1, '--problem-timeout', timeout]
                + TINY, tmp_path, 'faults') as b:
        os.kill(_started(b.proc, out / 'logs/box_panda/0001.log'), signal.SIGSTOP)
        assert b.wait() == 0, b.text()[-3000:]
    records = _records(out)
    hung = records['box_panda/0001']
    assert hung['outcome'] == 'timeout' and hung['timeout_s'] == timeout
    assert f'still running after {timeout} s' in hung['reason']
    assert hung['provenance']['by'] == 'driver' and hung['provenance']['commit']
    assert 'the driver' in (out / 'logs/box_panda/0001.log').read_text()
    for key, words in [('box_panda/0002', 'primitives'), ('box_panda/0003', 'request0003'),
                       ('box_panda/0004', 'scene0004')]:
        assert records[key]['outcome'] == 'refused' and words in records[key]['reason']
        made = records[key]['provenance']  # refused in a worker of the local Ray: 1 CPU, 1 thread
        assert made['cpus'] == 1 and made['threads'] == 1, made
    summary = json.loads((out / 'summary.json').read_text())
    pooled = next(g for g in summary['groups'] if g['family'] == 'all')
    assert pooled['outcomes']['timeout'] == 1 and pooled['outcomes']['refused'] == 3
    assert any(e.startswith('box_panda/0001: timeout') for e in summary['errors'])
    # The same limit keeps the timeout (no Ray); a larger one gives it another try. The
    # heatmap is the same by its content, wherever it lies.
    copied = tmp_path / 'elsewhere.npz'
    shutil.copy(robot_heatmap, copied)
    again = _run(['--problems', folder, '--families', 'box', '--out', out, '--heatmap', copied,
                  '--cpus-per-problem', 1, '--problem-timeout', timeout] + TINY)
    assert again.returncode == 0 and 'nothing to do' in again.stdout, again.stderr[-2000:]
    from advocc_ros.dataset.store import finished

    assert finished(out, 'box_panda', '0001', timeout) == hung
    assert finished(out, 'box_panda', '0001', timeout + 1) is None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _ray_node(args: list[str], env: dict, log: pathlib.Path, deadline: float) -> subprocess.Popen:
    """``ray start ARGS --block``, once it says the node's processes are up (asked of its
    output: ``ray status`` costs a process and ~2-4 CPU-s a call)."""
    with open(log, 'w') as out:
        proc = subprocess.Popen([RAY, 'start'] + args, env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    while 'Ray runtime started' not in log.read_text(errors='replace'):
        if proc.poll() is not None or time.monotonic() > deadline:
            _stop(proc)
            pytest.fail(f'ray start {args[0]}: not up\n{log.read_text(errors="replace")[-2000:]}')
        time.sleep(0.2)
    return proc


def _stop(proc: subprocess.Popen) -> None:
    """Stop a ``ray start --block`` and every process of its group (its Ray node)."""
    for sig, wait in ((signal.SIGTERM, 5), (signal.SIGKILL, 10)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            continue
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # what the group still holds (raylet, workers)
    except ProcessLookupError:
        pass


@pytest.mark.processes
def test_both_goal_forms_build_on_a_two_node_ray_cluster(tmp_path, robot_heatmap):
    port = _free_port()
    # A token of the test's own for every process of this cluster (none is read from or
    # written to ~/.ray).
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED='0', RAY_AUTH_MODE='token',
               RAY_AUTH_TOKEN=secrets.token_hex(32))
    for key in ('RAY_ADDRESS', 'RAY_AUTH_TOKEN_PATH'):
        env.pop(key, None)
    common = ['--num-cpus=1', '--node-ip-address=127.0.0.1', '--block', '--disable-usage-stats']
    nodes = []
    try:
        deadline = time.monotonic() + 90
        for name, args in (('head', ['--head', f'--port={port}', '--include-dashboard=false']),
                           ('worker', [f'--address=127.0.0.1:{port}'])):
            nodes.append(_ray_node(args + common, env, tmp_path / f'ray_{name}.log', deadline))
        status = [RAY, 'status', f'--address=127.0.0.1:{port}']
        while subprocess.run(status, env=env, capture_output=True,
                             text=True).stdout.count(' node_') < 2:  # the worker registered
            assert nodes[1].poll() is None and time.monotonic() < deadline, 'no worker node'
            time.sleep(1)
        out = tmp_path / 'out'
        address = ['--ray-address', f'127.0.0.1:{port}']
        args = ['--problems', REAL, '--families', 'box,table_pick', '--out', out, '--heatmap',
                robot_heatmap] + address + TINY[:-2] + ['--goal-form', 'both']
        refused = _run(args, env=env)  # 2 CPUs per problem by default: no node has them
        assert refused.returncode == 2 and 'no node of the Ray cluster' in refused.stderr
        assert not (out / 'build.json').exists()  # refused before any record was written
        run = _run(args + ['--cpus-per-problem', 1], env=env)
        assert run.returncode == 0, run.stderr[-3000:]
        for form in ('joint', 'region'):
            records = _records(out / form)
            assert [r['outcome'] for r in records.values()] == ['built', 'built'], records
            # One CPU per node and two problems at once: one problem ran on each node.
            assert len({r['provenance']['node'] for r in records.values()}) == 2, records
            entry = _build_record(out / form)['runs'][-1]
            assert entry['cluster']['nodes'] == 2 and entry['cluster']['resources']['CPU'] == 2
            assert entry['timing']['victims_cpus_alone'] is False
            for made in (r['provenance'] for r in records.values()):  # 1 CPU: one thread each
                assert made['victims_cpus_alone'] is False
                assert made['threads'] == 1
            summary = json.loads((out / form / 'summary.json').read_text())
            assert summary['made']['timing_of_built_problems']['shared'] == 2
            for key in records:  # the logs came back with the results
                assert 'attack at M=1' in (out / form / 'logs' / f'{key}.log').read_text()
        _both_goal_forms(out)
    finally:
        for proc in reversed(nodes):
            _stop(proc)


def _both_goal_forms(out: pathlib.Path) -> None:
    """--goal-form both: OUT/joint and OUT/region, each record and row naming its form, built
    on one Ray (started once: the same driver node); the joint export's request holds the
    request's own goal configuration and nothing else, and its witness ends there."""
    from advocc_ros.formats.mbm_export import load_trajectory
    from advocc_ros.formats.mbm_request import load_request
    from advocc_ros.model.robot import load_robot

    for form in ('joint', 'region'):
        assert _build_record(out / form)['settings']['build']['goal_form'] == form
        for key, record in _records(out / form).items():
            assert record['outcome'] == 'built', record
            attack = json.loads((out / form / key / 'hardness.json').read_text())['attacks']['1']
            assert attack['goal_form'] == form
        assert f',{form},built,' in (out / form / 'problems.csv').read_text()
        assert f'goal form `{form}`' in (out / form / 'summary.md').read_text()
    [joint], [region] = (_build_record(out / form)['runs'] for form in ('joint', 'region'))
    assert joint['cluster']['driver_node'] == region['cluster']['driver_node']
    robot = load_robot()
    for key in _records(out / 'joint'):
        family, number = key.split('/')
        folder = out / 'joint' / key / 'm1'
        own = load_request(REAL / family / f'request{number}.yaml', robot).goal
        exported = load_request(folder / f'request{number}.yaml', robot)
        assert exported.goal == own and exported.goal_region is None
        names, waypoints = load_trajectory(folder / f'trajectory{number}.yaml')
        assert [waypoints[-1][names.index(j)] for j in robot.joint_names] == \
            pytest.approx([own[j] for j in robot.joint_names], abs=1e-9)
