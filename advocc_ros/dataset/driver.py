"""The build on Ray: one Ray task per problem, resumable, with progress.

Without an address a local Ray is started in this process (``num_cpus`` = this machine's cores,
no dashboard, every socket on the loopback interface); with ``ray_address`` (``HOST:PORT`` of a
``ray start --head``) the build runs on that cluster, whose nodes must run this same
installation. A task whose worker process dies is retried by Ray (``max_retries``); one that
keeps dying is recorded as ``error``. Results come back to the driver as data and are written
here, atomically (``dataset.store``), as they arrive: a stopped build, run again with the same
settings and ``--out``, skips every finished problem.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import logging
import os
import pathlib
import sys
import time

from advocc_ros.dataset import store
from advocc_ros.dataset.heatmaps import heatmap_settings, robot_heatmaps
from advocc_ros.dataset.job import BuildConfig, problem_input, run_problem
from advocc_ros.dataset.problems import DatasetError, Problem, discover, select

log = logging.getLogger(__name__)

LOOPBACK_ENV = 'RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER'
"""Set to 0 before Ray is imported, Ray takes the loopback address as the node's and binds its
servers to it (its single-machine mode); otherwise a local Ray listens on every interface."""
HEARTBEAT_S = 30.0
"""Longest wait for a result before the progress shows again [s]."""


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """How the build is distributed (none of it changes a problem's result)."""

    ray_address: str | None = None
    """``HOST:PORT`` of a running Ray cluster; None: a local Ray in this process."""
    max_retries: int = 3
    """Times Ray runs a problem again after its worker process died."""
    cpus_per_problem: float = 1.0
    """Ray CPUs a problem holds (its planners run one at a time, so one core)."""
    heatmap_samples: int = 15_000
    """Valid samples of the robot-only heatmap (``HeatmapConfig.samples``' default)."""
    heatmap_seed: int = 0
    heatmap_file: str | None = None
    """A robot-only heatmap file to use instead of building one."""


@dataclasses.dataclass(frozen=True)
class Selection:
    """Which problems: the folder, families (None: all), split and the seeded limit."""

    root: str
    families: tuple[str, ...] | None = None
    split: str = 'all'
    limit: int | None = None
    seed: int = 0

    def problems(self) -> list[Problem]:
        return select(discover(self.root, list(self.families or ())), self.split, self.limit,
                      self.seed)


def build(selection: Selection, out: str | pathlib.Path, config: BuildConfig,
          run: RunConfig = RunConfig(), echo=None) -> dict:
    """Build (or resume) the data set of ``selection`` into ``out``; the build record
    (``build.json``): settings, counts, versions, times. Progress goes to stderr."""
    from advocc_ros.dataset.summary import write_summary

    echo = echo or (lambda text: print(text, file=sys.stderr, flush=True))
    out = pathlib.Path(out)
    problems = selection.problems()
    if not problems:
        raise DatasetError(f'{selection.root}: no problems in split {selection.split!r} of '
                           f'families {list(selection.families or []) or "all"}')
    settings = json.loads(json.dumps({'build': config.to_json(), 'heatmap': heatmap_settings(
        run.heatmap_samples, run.heatmap_seed, run.heatmap_file)}))  # as build.json reads back
    out.mkdir(parents=True, exist_ok=True)
    store.check_settings(out, settings)
    todo = interleaved([p for p in problems if store.finished(out, p.family, p.name) is None])
    record = {'format': 'advocc_dataset_build', 'version': 1, 'settings': settings,
              'selection': {**dataclasses.asdict(selection),
                            'root': str(pathlib.Path(selection.root).resolve()),
                            'problems': [p.key for p in problems]},
              'run': dataclasses.asdict(run), 'versions': versions(),
              'started': _now(), 'status': 'running', 'resumed': len(problems) - len(todo)}
    store.write_json(out / store.BUILD_FILE, record)
    echo(f'advocc dataset: {len(problems)} problems, {len(problems) - len(todo)} already '
         f'finished in {out}, {len(todo)} to build')
    t0 = time.perf_counter()
    counts = _run(todo, out, config, run, echo, record) if todo else {}
    record.update(status='finished', finished=_now(), wall_s=round(time.perf_counter() - t0, 3),
                  counts=counts)
    store.write_json(out / store.BUILD_FILE, record)
    record['summary'] = write_summary(out)
    return record


def interleaved(problems: list[Problem]) -> list[Problem]:
    """``problems`` taken one family at a time in turn (each family in its own order), so that
    a build stopped part-way has built about as many problems of every family."""
    families: dict[str, list[Problem]] = {}
    for p in problems:
        families.setdefault(p.family, []).append(p)
    queues = list(families.values())
    return [q[i] for i in range(max(map(len, queues), default=0)) for q in queues if i < len(q)]


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')


def _robots(problems: list[Problem], goal_tol) -> tuple[dict, list]:
    """``{problem key: robot hash}`` of the problems that load, and one scene per robot
    (those that do not load are refused by their job, with the parser's reason)."""
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.model.robot import load_robot

    hashes, scenes = {}, {}
    for p in problems:
        try:
            scene = load_any_scene(p.scene, p.request, goal_tol)
            h = load_robot(scene.robot).hash
        except Exception as exc:  # the job says why, as the problem's outcome
            log.info('%s does not load here: %s', p.key, exc)
            continue
        hashes[p.key] = h
        scenes.setdefault(h, scene)
    return hashes, list(scenes.values())


def _ray(run: RunConfig):
    """Ray, connected to ``run.ray_address`` or started here on the loopback interface."""
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    if run.ray_address is None:
        if 'ray' in sys.modules and os.environ.get(LOOPBACK_ENV) != '0':
            log.warning('ray was imported before the build: the local Ray may listen on '
                        'every interface')
        os.environ[LOOPBACK_ENV] = '0'
    import ray

    if run.ray_address is None:
        ray.init(address='local', num_cpus=os.cpu_count(), include_dashboard=False,
                 log_to_driver=False, namespace='advocc_dataset')
    else:
        try:
            ray.init(address=run.ray_address, log_to_driver=False, namespace='advocc_dataset')
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise DatasetError(f'--ray-address {run.ray_address}: cannot connect ({exc})') \
                from None
    return ray


def _run(todo: list[Problem], out: pathlib.Path, config: BuildConfig, run: RunConfig, echo,
         record: dict) -> dict:
    """Run ``todo`` on Ray, writing each result as it arrives; the outcome counts."""
    from advocc_ros.dataset.job import OUTCOMES
    from advocc_ros.progress import progress_bar

    hashes, scenes = _robots(todo, config.goal_tol)
    heatmaps = robot_heatmaps(scenes, out, run.heatmap_samples, run.heatmap_seed,
                              run.heatmap_file, workers=os.cpu_count() or 1, echo=echo)
    other = sorted(k for k, h in hashes.items() if h not in heatmaps)
    if other:  # only a given file can miss a robot: refuse before any work
        raise DatasetError(f'{run.heatmap_file}: built for robot '
                           f'{", ".join(map(str, heatmaps))}, not the robot of {other[0]} '
                           f'({hashes[other[0]]}) and {len(other) - 1} more problem(s)')
    ray = _ray(run)
    counts = dict.fromkeys(OUTCOMES, 0)
    pending: dict = {}
    bar = None
    try:
        record['cluster'] = {'address': run.ray_address or 'local',
                             'resources': ray.cluster_resources(),
                             'nodes': len([n for n in ray.nodes() if n.get('Alive')])}
        refs = {h: ray.put(hm) for h, hm in heatmaps.items()}
        task = ray.remote(num_cpus=run.cpus_per_problem, max_retries=run.max_retries,
                          retry_exceptions=False)(run_problem)
        for p in todo:
            pending[task.remote(problem_input(p), refs.get(hashes.get(p.key)), config)] = p
        bar = progress_bar(len(todo), 'dataset', 'problem', file=sys.stderr)
        t0 = time.monotonic()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=HEARTBEAT_S)
            if not ready:
                bar.update(0)  # a line in a log even while no problem finishes
            for ref in ready:
                p = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as exc:  # the worker kept dying: retries spent
                    result = _lost(p, run, exc)
                store.save_result(out, result)
                outcome = result['record']['outcome']
                counts[outcome] += 1
                if outcome != 'built':
                    bar.write(f'{p.key}: {outcome}: {result["record"]["reason"]}')
                done = len(todo) - len(pending)
                eta = (time.monotonic() - t0) / done * len(pending)
                shown = {k: v for k, v in counts.items() if v and k != 'error'}
                bar.set_postfix(done=done, failed=counts['error'], left=len(pending),
                                eta=_duration(eta), **shown)
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        for ref in pending:  # stopped: nothing of this build keeps running on a cluster
            try:
                ray.cancel(ref, force=True)
            except Exception:  # already finished or its node is gone
                pass
        ray.shutdown()
    return {k: v for k, v in counts.items() if v}


def _lost(p: Problem, run: RunConfig, exc: Exception) -> dict:
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return {'record': {'family': p.family, 'problem': p.name, 'split': p.split,
                       'outcome': 'error',
                       'reason': f'the worker died {run.max_retries + 1} times '
                                 f'({type(exc).__name__}: {reason})'},
            'hardness': None, 'files': {}}


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f'{seconds // 3600}h{seconds % 3600 // 60:02d}m'
    return f'{seconds // 60}m{seconds % 60:02d}s'


def versions() -> dict:
    """The tool's and its libraries' versions, and the checkout's commit."""
    import importlib.metadata
    import platform
    import subprocess

    out = {'python': platform.python_version(), 'platform': platform.platform()}
    for dist in ('advocc_ros', 'ray', 'numpy', 'scipy', 'ompl', 'pin', 'coal', 'trimesh',
                 'matplotlib', 'tesseract-robotics'):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = None
    repo = pathlib.Path(__file__).resolve().parents[2]
    # The MPlib victim's own venv (the checkout's; ADVOCC_MPLIB_PYTHON may name another).
    found = sorted(repo.glob('.venv-mplib/lib/python*/site-packages/mplib-*.dist-info'))
    out['mplib'] = found[-1].name[len('mplib-'):-len('.dist-info')] if found else None
    out['advocc_ros_commit'] = out['advocc_ros_modified'] = None
    try:
        git = [['git', '-C', str(repo)] + cmd for cmd in (
            ['rev-parse', 'HEAD'], ['status', '--porcelain', '--untracked-files=no', '--',
                                    'advocc_ros'])]
        commit, status = (subprocess.run(cmd, capture_output=True, text=True, timeout=10)
                          for cmd in git)
        if commit.returncode == 0:  # a checkout: its commit, and its code files changed since
            out['advocc_ros_commit'] = commit.stdout.strip()
            out['advocc_ros_modified'] = sorted(line[3:] for line in status.stdout.splitlines())
    except (OSError, subprocess.SubprocessError):
        pass
    return out


__all__ = ['RunConfig', 'Selection', 'build', 'interleaved', 'versions']
