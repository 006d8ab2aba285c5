"""A ROS 2 user's path, as the README's "Use in a ROS 2 workspace" gives it: this repository in a
workspace's src/, colcon builds advocc_msgs and advocc_ros, and the installed heatmap_server
answers ~/attack with the code and interfaces of the install space (not this checkout's)."""

import os
import pathlib
import re
import shutil
import subprocess
import sys
import time

import pytest

from advocc_ros.kernels.loader import HEADERS, SOURCES
from conftest import REPO
from test_attack_nodes import _call, _request, _stop

# one colcon build of both packages: ~1 min of C/C++ on 2 cores
pytestmark = [pytest.mark.slow, pytest.mark.processes]

# colcon does not look inside a package for more packages, and the repository root is one:
# msg_defs/ is named as a second base path (README).
BASE_PATHS = ('src', 'src/advocc_ros/msg_defs')
EXECUTABLES = ('heatmap_server', 'attacker', 'planner_shim', 'orchestrator')
_NOT_SOURCES = shutil.ignore_patterns('.git', '.venv*', 'build', 'install', 'log', 'out',
                                      '__pycache__', '*.egg-info', '.pytest_cache', '.hypothesis')


def _venv_env(base: dict) -> dict:
    """``base`` with the venv's ROS prefix as the underlay, as the README's commands set it, and
    no PYTHONPATH: only the install space may provide advocc_ros."""
    env = dict(base)
    env.pop('PYTHONPATH', None)
    env['VIRTUAL_ENV'] = sys.prefix
    env['PATH'] = os.pathsep.join([str(pathlib.Path(sys.prefix) / 'bin'), env.get('PATH', '')])
    env['AMENT_PREFIX_PATH'] = sys.prefix
    return env


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """A workspace with a copy of this repository in src/, built by ``colcon build``: the
    workspace path and colcon's output."""
    colcon = pathlib.Path(sys.executable).with_name('colcon')
    assert colcon.is_file(), f'no {colcon}: `make install` installs colcon (the test extra)'
    ws = tmp_path_factory.mktemp('ws')
    shutil.copytree(REPO, ws / 'src' / 'advocc_ros', ignore=_NOT_SOURCES)
    env = _venv_env(os.environ)
    env['COLCON_HOME'] = str(ws / 'colcon_home')  # no user defaults or mixins
    proc = subprocess.run([str(colcon), 'build', '--base-paths', *BASE_PATHS], cwd=ws, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, f'colcon build failed:\n{proc.stdout}\n{proc.stderr}'
    site = ws / 'install' / 'advocc_ros' / 'lib' / f'python3.{sys.version_info.minor}' / \
        'site-packages' / 'advocc_ros'
    # The kernels' C sources are installed: the same bytes name the library `make install`
    # built into the user's cache, which the install space loads as it is (kernels/loader.py).
    assert all((site / 'kernels' / name).is_file() for name in SOURCES + HEADERS)
    return ws, proc.stdout


def test_colcon_builds_both_packages_and_installs_the_executables(workspace):
    ws, output = workspace
    summary = re.search(r'^Summary: .*$', output, re.MULTILINE)
    print(summary and summary.group(0))
    assert summary and summary.group(0).startswith('Summary: 2 packages finished'), output
    assert 'Finished <<< advocc_msgs' in output and 'Finished <<< advocc_ros' in output
    lib = ws / 'install' / 'advocc_ros' / 'lib' / 'advocc_ros'
    for name in EXECUTABLES:
        assert os.access(lib / name, os.X_OK), f'{lib / name} is not an executable'
    share = ws / 'install' / 'advocc_ros' / 'share' / 'advocc_ros'
    assert (share / 'package.xml').is_file() and (share / 'config' / 'scenes').is_dir()
    msgs_share = ws / 'install' / 'advocc_msgs' / 'share' / 'advocc_msgs'
    assert (msgs_share / 'srv' / 'Attack.srv').is_file()

    # The installed package finds its shipped config (scenes, bench.yaml) in the install space.
    probe = subprocess.run(
        ['bash', '-c', f'source {ws}/install/setup.bash && python -c "from advocc_ros.paths '
         'import config_dir, scene_path; print(config_dir()); print(scene_path(\'table_pick\'))"'],
        cwd=ws, env=_venv_env(os.environ), capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0, probe.stderr
    config, scene = probe.stdout.split()
    assert pathlib.Path(config) == share / 'config' and pathlib.Path(scene).is_file()


def _loaded_files(verbose_log: str) -> list[str]:
    """Files of advocc_ros and advocc_msgs that ``PYTHONVERBOSE=1`` says were imported."""
    found = re.findall(r"(?:code object from|loaded from) '?([^'\s]+)", verbose_log)
    # bytecode written by an earlier import stands for its source: X/__pycache__/m.*.pyc -> X/m.py
    found = [re.sub(r'/__pycache__/([^/.]+)\.[^/]*\.pyc$', r'/\1.py', f) for f in found]
    return [f for f in found if re.search(r'/advocc_(?:ros|msgs)/', f)]


def test_the_installed_heatmap_server_answers_an_attack(
        workspace, ros, ros_env, heatmap_file, table_scene, tmp_path):  # noqa: F811
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack

    ws, _ = workspace
    node, executor, children = ros
    install = ws / 'install'
    env = _venv_env(ros_env)
    env['PYTHONVERBOSE'] = '1'  # every import, with its file: proof of where the code came from
    log_path = tmp_path / 'heatmap_server.log'
    command = (f'source {install}/setup.bash && exec {install}/advocc_ros/lib/advocc_ros/'
               f'heatmap_server --ros-args -p heatmap_file:={heatmap_file}')
    with open(log_path, 'w') as log:
        # From the workspace root, as a user would: a checkout as the working directory would
        # be on sys.path of the planning worker (python -c) and shadow the install space.
        server = subprocess.Popen(['bash', '-c', command], cwd=ws, env=env,
                                  stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    children.append(server)
    client = node.create_client(Attack, '/heatmap_server/attack')
    deadline = time.monotonic() + 120
    while not client.service_is_ready():
        if server.poll() is not None or time.monotonic() > deadline:
            lines = log_path.read_text(errors='replace').splitlines()
            node_lines = [line for line in lines if not line.startswith(('#', 'import '))]
            pytest.fail(f'the installed heatmap_server did not serve (exit code {server.poll()}):'
                        '\n' + '\n'.join(node_lines[-40:]))
        executor.spin_once(timeout_sec=0.1)

    answer = _call(executor, client, _request(table_scene), timeout_s=120)
    print(f'~/attack answered: error_code {answer.error_code.val}, '
          f'obstacles {[o.id for o in answer.obstacles]}, total_mass {answer.total_mass:.4f}, '
          f'{answer.compute_time_s * 1e3:.0f} ms, solvable {answer.solvable!r}')
    assert answer.error_code.val == ErrorCodes.SUCCESS, answer.message
    assert [o.id for o in answer.obstacles] == ['adv_0', 'adv_1', 'adv_2']
    assert answer.total_mass == pytest.approx(sum(o.covered_mass for o in answer.obstacles))

    # The interface libraries mapped into the server are the install space's (the venv holds a
    # second copy of advocc_msgs, built by make).
    maps = pathlib.Path(f'/proc/{server.pid}/maps').read_text()
    libs = set(re.findall(r'(/\S*libadvocc_msgs\S*\.so)', maps))
    assert libs and all(lib.startswith(f'{install}/advocc_msgs/') for lib in libs), libs
    assert _stop(server) == 0

    loaded = _loaded_files(log_path.read_text(errors='replace'))
    print(f'{len(loaded)} advocc files imported, e.g. {loaded[:1]}')
    assert loaded and all(f.startswith(f'{install}/') for f in loaded), \
        [f for f in loaded if not f.startswith(f'{install}/')]
    site = f'{install}/advocc_ros/lib/python3.{sys.version_info.minor}/site-packages/advocc_ros'
    assert any(f.startswith(f'{site}/nodes/heatmap_server') for f in loaded), loaded
    assert any(f.startswith(f'{install}/advocc_msgs/') and '_attack' in f for f in loaded), loaded
