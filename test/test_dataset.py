"""``advocc dataset build`` on real MotionBenchMaker problems (test/data/mbm_real): problem
selection and bad input in-process, then real builds as the CLI runs them, on an embedded Ray,
on a two-node Ray cluster of separate ``ray start`` processes, with a worker killed mid-problem,
with malformed problems, and resumed. Tiny settings (one box, one RRTConnect trial of 1 s)
keep each build to seconds of CPU; the witness cache of the session is shared, so a problem's
witness is searched once for all tests."""

import csv
import json
import os
import pathlib
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time

import pytest

from advocc_ros.dataset.problems import DatasetError, discover, select, split_of

REPO = pathlib.Path(__file__).resolve().parents[1]
REAL = REPO / 'test' / 'data' / 'mbm_real'
ADVOCC = [sys.executable, '-m', 'advocc_ros.cli']
RAY = str(pathlib.Path(sys.executable).with_name('ray'))
TINY = ['--budgets', '1', '--victims', 'rrtconnect', '--trials', '1', '--time', '1']
"""One box, one RRTConnect trial of 1 s: the smallest build that runs every step."""


def _run(args, env=None, timeout=300) -> subprocess.CompletedProcess:
    env = dict(env or os.environ, PYTHONUNBUFFERED='1')
    return subprocess.run(ADVOCC + ['dataset', 'build'] + [str(a) for a in args], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=timeout)


def _records(out: pathlib.Path) -> dict:
    return {f'{p.parent.parent.name}/{p.parent.name}': json.loads(p.read_text())
            for p in sorted(out.glob('*/*/outcome.json'))}


@pytest.fixture(scope='module')
def robot_heatmap(tmp_path_factory):
    """A small robot-only heatmap of the MotionBenchMaker Panda (fingers as its files lock
    them), shared by the builds that do not test the heatmap's own build."""
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap

    scene = load_any_scene(REAL / 'box_panda' / 'scene0001.yaml',
                           REAL / 'box_panda' / 'request0001.yaml')
    path = tmp_path_factory.mktemp('robot_heatmap') / 'panda_robot_only.npz'
    save_heatmap(build_heatmap(scene, HeatmapConfig(samples=1000, robot_only=True), seed=0),
                 path)
    return path


# --------------------------------------------------------------------------------------------
# Selection and bad input (no process)

def test_split_and_seeded_selection(tmp_path):
    for family in ('box_panda', 'cage_panda'):
        (tmp_path / family).mkdir()
        for i in (1, 2, 39, 40, 41, 42, 77, 100):
            (tmp_path / family / f'scene{i:04d}.yaml').write_text('{}')
    problems = discover(tmp_path)
    assert len(problems) == 16 and [split_of(i) for i in (1, 40, 41, 100)] == [
        'train', 'train', 'test', 'test']
    train = select(problems, 'train')
    assert {p.index for p in train} == {1, 2, 39, 40}
    test = select(problems, 'test', limit=2, seed=3)
    assert len(test) == 4 and all(p.index > 40 for p in test)
    assert test == select(problems, 'test', limit=2, seed=3)  # the seed decides, not the order
    draws = {tuple(p.key for p in select(problems, 'test', limit=2, seed=s)) for s in range(8)}
    assert len(draws) > 1
    # One family's choice does not depend on which other families are built.
    alone = select(discover(tmp_path, ['cage']), 'test', limit=2, seed=3)
    assert alone == [p for p in test if p.family == 'cage_panda']
    # A build takes the families in turn: stopped part-way, it has some of each.
    from advocc_ros.dataset.driver import interleaved

    order = interleaved(test + [p for p in train if p.family == 'box_panda'])
    assert [p.family[:3] for p in order] == ['box', 'cag'] * 2 + ['box'] * 4
    assert [p for p in order if p.family == 'box_panda'] == [
        p for p in test + train if p.family == 'box_panda']
    assert interleaved([]) == []


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
            (['--problems', REAL, '--split', 'test'], 'no problems in split')]:
        assert main(['dataset', 'build', '--out', str(out)] + [str(a) for a in args]) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['dataset', 'build', '--problems', str(REAL), '--out', str(out), '--split', 'x'])


@pytest.mark.processes  # build.json records the checkout's commit (git)
def test_a_heatmap_that_does_not_fit_is_refused_before_any_work(tmp_path, heatmap_file):
    from advocc_ros.dataset.driver import RunConfig, Selection, build
    from advocc_ros.dataset.job import BuildConfig
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    from advocc_ros.model.scene import load_scene

    selection = Selection(str(REAL), ('box',))
    with pytest.raises(DatasetError, match='scene-conditioned heatmap fits one scene'):
        build(selection, tmp_path / 'a', BuildConfig(), RunConfig(heatmap_file=str(
            heatmap_file)))
    # The problems' Panda locks its fingers at 0.04, the shipped box scene's robot does not.
    other = tmp_path / 'srdf_fingers.npz'
    save_heatmap(build_heatmap(load_scene(REPO / 'config' / 'scenes' / 'box.yaml'),
                               HeatmapConfig(samples=200, robot_only=True)), other)
    with pytest.raises(DatasetError, match='not the robot of box_panda/0001'):
        build(selection, tmp_path / 'b', BuildConfig(), RunConfig(heatmap_file=str(other)))
    assert not list((tmp_path / 'b').glob('*/*/outcome.json'))


# --------------------------------------------------------------------------------------------
# Builds (each starts Ray and planner processes)

@pytest.fixture(scope='module')
def built(tmp_path_factory):
    """Two real problems built on the embedded Ray, the robot-only heatmap built too: the
    output folder and the CLI's run."""
    out = tmp_path_factory.mktemp('dataset') / 'out'
    t0 = time.monotonic()
    run = _run(['--problems', REAL, '--families', 'box,table_pick', '--out', out,
                '--heatmap-samples', 1000] + TINY)
    print(f'embedded build: {time.monotonic() - t0:.1f} s wall')
    return out, run


@pytest.mark.processes
def test_build_on_embedded_ray(built):
    from advocc_ros.formats.mbm_export import load_trajectory
    from advocc_ros.formats.mbm_scene import load_any_scene

    out, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    assert '2 built' in run.stdout and 'done=2, failed=0, left=0' in run.stderr
    records = _records(out)
    assert sorted(records) == ['box_panda/0001', 'table_pick_panda/0001']
    for key, record in records.items():
        assert record['outcome'] == 'built' and record['split'] == 'train', record
        folder = out / key
        hardness = json.loads((folder / 'hardness.json').read_text())
        attack = hardness['attacks']['1']
        assert attack['certificate'] == 'certified' and attack['boxes'] == 1
        cell = attack['victims']['rrtconnect']
        assert cell['trials'] == 1 and set(cell['failures']) >= {'timed out', 'goal not sampled'}
        assert 'first_solution_median_s' in cell and 'pt_ratio' in cell
        assert hardness['unattacked']['rrtconnect']['trials'] == 1
        # The exported problem reads back: the scene's objects and the box, its witness.
        family = key.split('/')[0]
        original = load_any_scene(REAL / family / 'scene0001.yaml',
                                  REAL / family / 'request0001.yaml')
        exported = load_any_scene(folder / 'm1' / 'scene0001.yaml',
                                  folder / 'm1' / 'request0001.yaml')
        assert len(exported.objects) == len(original.objects) + 1
        names, waypoints = load_trajectory(folder / 'm1' / 'trajectory0001.yaml')
        assert len(names) == 7 and len(waypoints) == attack['witness_waypoints']
    assert len(list((out / 'heatmaps').glob('robot-*.npz'))) == 1  # one robot, one heatmap
    build = json.loads((out / 'build.json').read_text())
    assert build['status'] == 'finished' and build['counts'] == {'built': 2}
    assert build['versions']['ray'] == '2.60.0' and build['versions']['numpy']
    assert build['settings']['build']['budgets'] == [1]
    assert build['selection']['problems'] == ['box_panda/0001', 'table_pick_panda/0001']
    summary = json.loads((out / 'summary.json').read_text())
    pooled = next(g for g in summary['groups'] if g['family'] == 'all')
    assert pooled['split'] == 'train' and pooled['problems'] == 2
    assert pooled['shares']['built'] == 1.0 and pooled['budgets']['1']['evaluated'] == 2
    assert '| box_panda | 1 |' in (out / 'summary.md').read_text()
    assert (out / 'summary.png').read_bytes()[:4] == b'\x89PNG'
    # problems.csv: per problem, the unattacked row and the attacked one, per victim.
    rows = list(csv.DictReader((out / 'problems.csv').open()))
    assert [(r['family'], r['budget'], r['victim']) for r in rows] == [
        ('box_panda', '0', 'rrtconnect'), ('box_panda', '1', 'rrtconnect'),
        ('table_pick_panda', '0', 'rrtconnect'), ('table_pick_panda', '1', 'rrtconnect')]
    attacked = json.loads((out / 'box_panda/0001/hardness.json').read_text())['attacks']['1']
    assert rows[1]['certificate'] == 'certified' and rows[1]['boxes'] == '1'
    assert float(rows[1]['psr']) == attacked['victims']['rrtconnect']['psr']


@pytest.mark.processes  # the `built` fixture runs a build
def test_summary_rewrites_a_build_folders_summary(built, tmp_path, capsys):
    """``advocc dataset summary`` summarises what a folder holds (a stopped build's too); a
    folder without a build record is a clear error."""
    from advocc_ros.cli import main

    out, _ = built
    copy = tmp_path / 'copy'
    shutil.copytree(out, copy)
    shutil.rmtree(copy / 'table_pick_panda')  # as if stopped before its second problem
    for name in ('summary.json', 'summary.md', 'problems.csv'):
        (copy / name).unlink()
    assert main(['dataset', 'summary', str(copy)]) == 0
    assert '| box_panda | 1 |' in capsys.readouterr().out
    summary = json.loads((copy / 'summary.json').read_text())
    assert summary['problems'] == 1 and len((copy / 'problems.csv').read_text().splitlines()) == 3
    assert main(['dataset', 'summary', str(tmp_path / 'nowhere')]) == 2
    assert 'not a data set build folder' in capsys.readouterr().err


@pytest.mark.processes
def test_resume_redoes_only_unfinished_problems(built, robot_heatmap):
    out, run = built
    assert run.returncode == 0, run.stderr[-3000:]
    before = _records(out)
    # A stop between a problem's files and its outcome record: that problem is redone.
    (out / 'table_pick_panda' / '0001' / 'outcome.json').unlink()
    again = _run(['--problems', REAL, '--families', 'box,table_pick', '--out', out,
                  '--heatmap-samples', 1000] + TINY)
    assert again.returncode == 0, again.stderr[-3000:]
    assert '1 already finished' in again.stderr and 'this run: 1 built' in again.stdout
    after = _records(out)
    assert after['box_panda/0001'] == before['box_panda/0001']  # not redone
    assert after['table_pick_panda/0001']['outcome'] == 'built'
    # Nothing left: no Ray is started at all; other settings are refused.
    third = _run(['--problems', REAL, '--families', 'box,table_pick', '--out', out,
                  '--heatmap-samples', 1000] + TINY)
    assert third.returncode == 0 and 'nothing to do' in third.stdout
    assert 'Ray' not in third.stderr
    other = _run(['--problems', REAL, '--families', 'box', '--out', out, '--heatmap-samples',
                  1000] + TINY[:-2] + ['--time', '2'])
    assert other.returncode == 2 and 'other settings (build)' in other.stderr


@pytest.mark.processes
def test_malformed_problems_are_refused_and_the_rest_built(tmp_path, robot_heatmap):
    problems = tmp_path / 'problems' / 'box_panda'
    problems.mkdir(parents=True)
    for name in ('scene0001.yaml', 'request0001.yaml'):
        shutil.copy(REAL / 'box_panda' / name, problems / name)
    text = (REAL / 'box_panda' / 'scene0001.yaml').read_text()
    assert 'type: box' in text
    (problems / 'scene0002.yaml').write_text(text.replace('type: box', 'type: blob', 1))
    shutil.copy(REAL / 'box_panda' / 'request0001.yaml', problems / 'request0002.yaml')
    (problems / 'scene0003.yaml').write_text(text)  # no request0003.yaml
    (problems / 'scene0004.yaml').write_text('world: [unclosed\n')
    shutil.copy(REAL / 'box_panda' / 'request0001.yaml', problems / 'request0004.yaml')
    out = tmp_path / 'out'
    run = _run(['--problems', tmp_path / 'problems', '--out', out, '--heatmap', robot_heatmap]
               + TINY)
    assert run.returncode == 0, run.stderr[-3000:]
    records = _records(out)
    assert records['box_panda/0001']['outcome'] == 'built'
    for key, words in [('box_panda/0002', 'primitives'), ('box_panda/0003', 'request0003'),
                       ('box_panda/0004', 'scene0004')]:
        assert records[key]['outcome'] == 'refused', records[key]
        assert words in records[key]['reason'], records[key]
    summary = json.loads((out / 'summary.json').read_text())
    pooled = next(g for g in summary['groups'] if g['family'] == 'all')
    assert pooled['outcomes']['refused'] == 3 and pooled['shares']['built'] == 0.25


@pytest.mark.processes
def test_a_killed_worker_is_retried_and_every_problem_done_once(tmp_path, robot_heatmap):
    from advocc_ros.dataset.job import KILL_ONCE_ENV

    marker = tmp_path / 'killed'
    out = tmp_path / 'out'
    run = _run(['--problems', REAL, '--families', 'box,table_pick', '--out', out, '--heatmap',
                robot_heatmap] + TINY, env=dict(os.environ, **{KILL_ONCE_ENV: str(marker)}))
    assert run.returncode == 0, run.stderr[-3000:]
    killed = int(marker.read_text())  # the hook killed a worker: SIGKILL, no clean-up
    records = _records(out)
    assert sorted(records) == ['box_panda/0001', 'table_pick_panda/0001']
    assert all(r['outcome'] == 'built' for r in records.values()), records
    assert killed not in {r['pid'] for r in records.values()}
    build = json.loads((out / 'build.json').read_text())
    assert build['counts'] == {'built': 2}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


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
def test_build_on_a_two_node_ray_cluster(tmp_path, robot_heatmap):
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
        nodes.append(subprocess.Popen(
            [RAY, 'start', '--head', f'--port={port}', '--include-dashboard=false'] + common,
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))
        status = [RAY, 'status', f'--address=127.0.0.1:{port}']
        deadline = time.monotonic() + 60
        while subprocess.run(status, env=env, capture_output=True).returncode != 0:
            assert nodes[0].poll() is None and time.monotonic() < deadline, 'no Ray head'
            time.sleep(1)
        nodes.append(subprocess.Popen(
            [RAY, 'start', f'--address=127.0.0.1:{port}'] + common, env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        while subprocess.run(status, env=env, capture_output=True,
                             text=True).stdout.count(' node_') < 2:
            assert nodes[1].poll() is None and time.monotonic() < deadline, 'no worker node'
            time.sleep(1)
        out = tmp_path / 'out'
        run = _run(['--problems', REAL, '--families', 'box,table_pick', '--out', out,
                    '--heatmap', robot_heatmap, '--ray-address', f'127.0.0.1:{port}'] + TINY,
                   env=env)
        assert run.returncode == 0, run.stderr[-3000:]
        records = _records(out)
        assert [r['outcome'] for r in records.values()] == ['built', 'built'], records
        # One CPU per node and two problems at once: one problem ran on each node.
        assert len({r['node'] for r in records.values()}) == 2, records
        build = json.loads((out / 'build.json').read_text())
        assert build['cluster']['nodes'] == 2 and build['cluster']['resources']['CPU'] == 2
    finally:
        for proc in reversed(nodes):
            _stop(proc)
