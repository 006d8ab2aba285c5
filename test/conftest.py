"""Shared fixtures: seeded RNGs, the Panda model, a small scene and its heatmap file, a unique
ROS domain per test and an rclpy client on it."""

import os
import pathlib
import random
import shutil

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which('chromium')
"""Debian's headless Chromium, which draws the 3D page and Planner Arena (``.ci/run``
installs it)."""
FAST_LANE_ENV = 'ADVOCC_FAST_LANE'
"""Set by ``make test-fast``: tests marked ``processes`` are deselected, and any other test that
starts a process fails, naming itself, so the marks stay true."""


def needs_chromium():
    """Skip the calling test, saying why, on a machine without Chromium."""
    if CHROMIUM is None:
        reason = 'chromium is not installed (apt-get install -y chromium; .ci/run does)'
        print(f'skipped: {reason}')
        pytest.skip(reason)


def pytest_configure(config):
    if os.environ.get(FAST_LANE_ENV) == '1':
        _refuse_processes()


def _refuse_processes():
    import multiprocessing.util
    import subprocess

    def refuse(*args, **kwargs):
        raise RuntimeError(f'this test starts a process: mark it @pytest.mark.processes '
                           f'(module: pytestmark), the fast lane ({FAST_LANE_ENV}=1) runs none')

    subprocess.Popen._execute_child = refuse
    os.fork = refuse
    os.posix_spawn = refuse
    multiprocessing.util.spawnv_passfds = refuse


@pytest.fixture(autouse=True, scope='session')
def _witness_cache(tmp_path_factory):
    """Witnesses found by one test's processes are reused by later ones, as on a user's
    machine, but never read from or written to the user's own cache."""
    from advocc_ros.planning.witness import CACHE_ENV
    os.environ[CACHE_ENV] = str(tmp_path_factory.mktemp('witness_cache'))
    yield


@pytest.fixture(autouse=True)
def _seed():
    random.seed(0)
    np.random.seed(0)


@pytest.fixture(scope='session')
def panda():
    from advocc_ros.model.robot import load_robot
    return load_robot()


@pytest.fixture(scope='session')
def table_scene():
    from advocc_ros.model.scene import load_scene
    return load_scene(REPO / 'config' / 'scenes' / 'table_pick.yaml')


_domain = [100 + os.getpid() % 50]


@pytest.fixture
def ros_env():
    """Environment for child ROS processes, isolated on a ROS_DOMAIN_ID of its own."""
    _domain[0] = 100 + (_domain[0] - 99) % 130
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(_domain[0])
    env['ROS_LOCALHOST_ONLY'] = '1'
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture(scope='module')
def heatmap_file(tmp_path_factory, table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    path = tmp_path_factory.mktemp('heatmap') / 'h500.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=500), seed=2), path)
    return path


@pytest.fixture
def ros(ros_env, monkeypatch):
    """rclpy in this process on the children's domain; children are always killed."""
    import rclpy

    for key in ('ROS_DOMAIN_ID', 'ROS_LOCALHOST_ONLY'):
        monkeypatch.setenv(key, ros_env[key])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('attack_test_client', context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    children = []
    try:
        yield node, executor, children
    finally:
        for proc in children:
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
