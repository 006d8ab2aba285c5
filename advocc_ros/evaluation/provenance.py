"""What made a record: the code (its commit, and whether its files differ from it), the machine
(host, CPU model, the cores this process may use, the load, and how fast it plans: ``speed``)
and the libraries' versions.

A figure is only as good as what it names of its making: every record of a data set carries
this, so that a table can be traced to a commit and a machine, and a figure measured on a loaded
or a modified checkout can be told from one that was not. The commit and the versions are read
once per process (the code a process runs is the code it imported); the load at every call.
"""

from __future__ import annotations

import datetime
import functools
import importlib.metadata
import os
import pathlib
import platform
import socket
import statistics
import subprocess
import time

import numpy as np

from advocc_ros.limits import available_cpus

REPO = pathlib.Path(__file__).resolve().parents[2]
"""The checkout this package runs from, when it runs from one (not an installed copy)."""
CODE_PATHS = ('advocc_ros', 'config', 'setup.py')
"""What ``dirty`` looks at: the code and the robot and scene files it loads, not docs or
results (a results README edited before a build does not change a figure)."""
DISTRIBUTIONS = ('advocc_ros', 'ray', 'numpy', 'scipy', 'ompl', 'pin', 'coal', 'trimesh',
                 'matplotlib', 'tesseract-robotics')
"""Libraries whose versions every record names (None: not installed)."""


def now() -> str:
    """The time, UTC, to the second, ISO 8601."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')


@functools.lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; elsewhere what ``platform`` knows)."""
    try:
        with open('/proc/cpuinfo', encoding='utf-8', errors='replace') as handle:
            for line in handle:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load() -> list[float]:
    """The machine's load average over 1, 5 and 15 minutes (runnable processes)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return []


@functools.lru_cache(maxsize=1)
def code() -> dict:
    """``commit`` (None outside a git checkout of this package), ``dirty`` (files of
    ``CODE_PATHS`` changed since the commit or not in it, ignored ones aside) and ``modified``
    (those files)."""
    out = {'commit': None, 'dirty': None, 'modified': []}
    git = ['git', '-C', str(REPO)]
    try:
        top = _git(git + ['rev-parse', '--show-toplevel'])
        if top is None or pathlib.Path(top.strip()).resolve() != REPO:  # another repository's
            return out
        commit = _git(git + ['rev-parse', 'HEAD'])
        status = _git(git + ['status', '--porcelain', '--untracked-files=all', '--']
                      + list(CODE_PATHS))
    except (OSError, subprocess.SubprocessError):
        return out
    if commit is None or status is None:
        return out
    modified = sorted(line[3:] for line in status.splitlines() if line.strip())
    return {'commit': commit.strip(), 'dirty': bool(modified), 'modified': modified}


def _git(cmd: list[str]) -> str | None:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=20)
    return done.stdout if done.returncode == 0 else None


@functools.lru_cache(maxsize=1)
def versions() -> dict:
    """Python's, the platform's and ``DISTRIBUTIONS``' versions, the compiled kernels' (the
    digest of their sources and flags, and the compiler's version), and MPlib's in the venv the
    MPlib victim runs in (``$ADVOCC_MPLIB_PYTHON``'s, else the checkout's ``.venv-mplib``)."""
    from advocc_ros.kernels.loader import compiler_version, digest
    from advocc_ros.planning.victims.mplib import PYTHON_ENV

    out = {'python': platform.python_version(), 'platform': platform.platform(),
           'kernels': digest(), 'kernels_compiler': compiler_version()}
    for dist in DISTRIBUTIONS:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = None
    venvs = [REPO / '.venv-mplib']
    if os.environ.get(PYTHON_ENV):  # the venv of the interpreter the victim runs
        venvs.insert(0, pathlib.Path(os.environ[PYTHON_ENV]).parent.parent)
    found = [sorted(v.glob('lib/python*/site-packages/mplib-*.dist-info')) for v in venvs]
    found = next((f for f in found if f), [])
    out['mplib'] = found[-1].name[len('mplib-'):-len('.dist-info')] if found else None
    return out


def machine() -> dict:
    """``host``, ``cpu`` (model), ``cores`` (this process may use: ``limits.available_cpus``),
    ``machine_cores`` and ``load`` (1, 5, 15 min)."""
    return {'host': socket.gethostname(), 'cpu': cpu_model(), 'cores': available_cpus(),
            'machine_cores': os.cpu_count(), 'load': load()}


SPEED_SCENE = 'table_pick'
SPEED_CONFIGURATIONS = 1000
SPEED_ROUNDS = 5
SPEED_SPREAD = 1.5
"""Machines whose speeds (``speed``, each one's median) differ by more than this factor do
not pool time-bound figures: a 5 s budget buys that much more planning on the faster one. One
virtual machine's probes drift within a minute (twenty on a 2-core AMD EPYC: 32,187 to
52,388/s, docs/results/machine_speed), so a machine is judged by the median of its records."""


def validity_checks_per_s(world, Q: np.ndarray) -> float:
    """Collision checks per second of ``world`` over the configurations ``Q``, one at a time
    from Python, as a victim's validity checker is called."""
    t0 = time.perf_counter()
    for q in Q:
        world.in_collision(q)
    return len(Q) / (time.perf_counter() - t0)


def speed() -> float:
    """How fast this machine plans, now: validity checks per second of the default Panda on
    the shipped ``SPEED_SCENE`` (the median of ``SPEED_ROUNDS`` rounds over the same
    ``SPEED_CONFIGURATIONS`` random configurations, after one round of warm-up; ~0.2 s on a
    2-core AMD EPYC, median 36,715/s). The CPU model does not say it: two machines named AMD
    EPYC differed 2.5x. Planners' wall-clock budgets buy planning in proportion to it, so a
    data set's records are comparable in PSR only when their machines' speeds are close."""
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import load_scene
    from advocc_ros.paths import scene_path

    scene = load_scene(scene_path(SPEED_SCENE))
    robot = load_robot(scene.robot)
    world = CollisionWorld(robot, scene.shapes)
    Q = robot.sample_q(np.random.default_rng(0), SPEED_CONFIGURATIONS)
    validity_checks_per_s(world, Q)
    return round(statistics.median(validity_checks_per_s(world, Q) for _ in range(SPEED_ROUNDS)),
                 1)


def speed_spread(speeds: list[float]) -> float | None:
    """The fastest of ``speeds`` over the slowest (None for fewer than two)."""
    known = [v for v in speeds if v]
    return round(max(known) / min(known), 3) if len(known) > 1 else None


def stamp() -> dict:
    """The few fields one trial's record names of its making (a bench's ``records.jsonl``):
    ``commit``, ``dirty``, ``host``, ``cpu`` and ``load_1min``, the machine's load when it was
    recorded."""
    made, where = code(), machine()
    return {'commit': made['commit'], 'dirty': made['dirty'], 'host': where['host'],
            'cpu': where['cpu'], 'load_1min': where['load'][0] if where['load'] else None}


def record() -> dict:
    """Everything above in one dict: ``code()``, ``machine()`` and ``versions``."""
    return {**code(), **machine(), 'versions': versions()}


__all__ = ['CODE_PATHS', 'DISTRIBUTIONS', 'REPO', 'SPEED_SCENE', 'SPEED_SPREAD',
           'code', 'cpu_model', 'load', 'machine', 'now', 'record', 'speed', 'speed_spread',
           'stamp', 'validity_checks_per_s', 'versions']
