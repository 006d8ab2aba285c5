"""Shared fixtures: seeded RNGs, the Panda model, a small scene and its heatmap file, a unique
ROS domain per test and an rclpy client on it; and how the suite shares the machine's CPUs when
pytest-xdist runs it on several workers (``setup.cfg``: ``-n 2 --dist loadfile``)."""

import fcntl
import os
import pathlib
import random
import shutil
import signal

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which('chromium')
"""Debian's headless Chromium, which draws the 3D page and Planner Arena (``.ci/run``
installs it)."""
FAST_LANE_ENV = 'ADVOCC_FAST_LANE'
"""Set by ``make test-fast``: tests marked ``processes`` are deselected, and any other test that
starts a process fails, naming itself, so the marks stay true."""


def ctrl_c_as_in_a_terminal() -> None:
    """SIGINT back to its default in a child (``preexec_fn``), as in a terminal's foreground
    job: a test run started as a background job of a shell (``cmd &``) inherits it ignored, and
    so would every process it starts (a Ctrl-C test then measures the launcher, not the child)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def needs_chromium():
    """Skip the calling test, saying why, on a machine without Chromium."""
    if CHROMIUM is None:
        reason = 'chromium is not installed (apt-get install -y chromium; .ci/run does)'
        print(f'skipped: {reason}')
        pytest.skip(reason)


def _xdist_controller(config) -> bool:
    """Whether this process is pytest-xdist's controller: it starts the workers (processes)
    and runs no test itself."""
    return bool(getattr(config.option, 'numprocesses', None)) and \
        not hasattr(config, 'workerinput')


@pytest.hookimpl(trylast=True)  # after an xdist worker describes its platform (`uname -p`)
def pytest_sessionstart(session):
    # The fast lane refuses processes, from before collection, in every process that runs
    # tests: the workers under xdist, this one without it (the controller starts the workers).
    if os.environ.get(FAST_LANE_ENV) == '1' and not _xdist_controller(session.config):
        _refuse_processes()


# --------------------------------------------------------------------------------------------
# Two workers on two cores: what runs together
#
# pytest-xdist sends each worker a test module at a time (``--dist=loadfile``: module fixtures
# are made once, a fuzz module's case counts see all its tests, and a module's nodes, Ray
# clusters and run folders never meet their twins). A test marked ``timing`` (it measures time
# or plans against a budget it must meet) runs while no other test runs: the other worker
# waits (a readers-writer lock on a file in the run's temporary folder, writers first).

SLOWEST_FIRST = ('test_dataset.py', 'test_collision_exact.py', 'test_orchestrator.py',
                 'test_audit.py', 'test_task.py', 'test_workspace.py', 'test_solvable.py',
                 'test_fuzz_parsers.py', 'test_perf_load.py', 'test_attack_nodes.py')
"""The modules that took longest (``--durations``), handed out first so that the short ones
even out the two workers' ends (``--no-loadscope-reorder`` keeps this order)."""


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: module order kept


class CpuTurns:
    """The run's CPU lock as one worker holds it (a file lock in ``root``): shared for an
    ordinary test, exclusive for a ``timing`` one. A waiting timing test holds the turn, so no
    new test passes it; it then waits for the tests running on the other workers to end. An
    exclusive turn is kept while the worker's next test is ``timing`` too: 18 timing tests in a
    row wait once for the other worker, not 18 times (each wait left a core idle)."""

    def __init__(self, root: pathlib.Path):
        self._turn = open(root / 'cpu.turn', 'a')
        self._lock = open(root / 'cpu.lock', 'a')
        self.alone: bool | None = None
        """How the lock is held: None (not), False (shared), True (exclusive)."""

    def take(self, alone: bool) -> None:
        if alone and self.alone:
            return  # kept from the timing test before
        self.give_back()
        fcntl.flock(self._turn, fcntl.LOCK_EX)
        fcntl.flock(self._lock, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(self._turn, fcntl.LOCK_UN)
        self.alone = alone

    def give_back(self) -> None:
        if self.alone is not None:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self.alone = None


_TURNS = pytest.StashKey[CpuTurns]()


def _timing(item) -> bool:
    return item is not None and item.get_closest_marker('timing') is not None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Set-up (module fixtures included), call and tear-down inside the CPU lock."""
    base = getattr(item.config.option, 'basetemp', None)
    if not hasattr(item.config, 'workerinput') or not base:
        yield  # one process runs every test: nothing runs beside it
        return
    if _TURNS not in item.config.stash:  # the workers' folders are popen-gw0, popen-gw1, ...
        item.config.stash[_TURNS] = CpuTurns(pathlib.Path(base).parent)
    turns = item.config.stash[_TURNS]
    turns.take(_timing(item))
    try:
        yield
    finally:
        if not (_timing(item) and _timing(nextitem)):
            turns.give_back()


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
    """Witnesses found by one test's processes are reused by later ones (those of every
    worker), as on a user's machine, but never read from or written to the user's own cache."""
    from advocc_ros.planning.witness import CACHE_ENV
    base = tmp_path_factory.getbasetemp()
    if 'PYTEST_XDIST_WORKER' in os.environ:  # base is popen-gwN: its parent is the run's
        folder = base.parent / 'witness_cache'
        folder.mkdir(exist_ok=True)
    else:
        folder = tmp_path_factory.mktemp('witness_cache')
    os.environ[CACHE_ENV] = str(folder)
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


ROS_DOMAINS = range(100, 230)
"""The ROS_DOMAIN_IDs tests use; each xdist worker draws from its own slice of them."""
_domain: list[int] = []


def fresh_domain() -> int:
    """A ROS_DOMAIN_ID no other test of this run uses meanwhile: the next of this worker's
    slice of ``ROS_DOMAINS``, from an offset set by the pid (another run on the machine
    likely starts elsewhere)."""
    index = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0')[2:])
    size = len(ROS_DOMAINS) // int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    _domain[:] = [(_domain[0] + 1) % size if _domain else os.getpid() % size]
    return ROS_DOMAINS[0] + index * size + _domain[0]


@pytest.fixture
def ros_env():
    """Environment for child ROS processes, isolated on a ROS_DOMAIN_ID of its own."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(fresh_domain())
    env['ROS_LOCALHOST_ONLY'] = '1'
    env['PYTHONUNBUFFERED'] = '1'
    return env


def _run_folder(tmp_path_factory) -> pathlib.Path:
    """The run's temporary folder that every xdist worker shares (a worker's own is
    ``popen-gwN`` inside it); without xdist, this process's."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if 'PYTEST_XDIST_WORKER' in os.environ else base


@pytest.fixture(scope='session')
def heatmap_file(tmp_path_factory, table_scene):
    """table_pick's heatmap of 500 samples (seed 2), built once for the whole run: the first
    worker to need it builds it under a lock, every module of both workers reads the same
    file (none writes to it; a seeded build is the same on any worker)."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    folder = _run_folder(tmp_path_factory) / 'shared_heatmap'
    folder.mkdir(exist_ok=True)
    path = folder / 'h500.npz'
    with open(folder / 'build.lock', 'a') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not path.exists():  # save_heatmap writes atomically
                save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=500), seed=2),
                             path)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
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
