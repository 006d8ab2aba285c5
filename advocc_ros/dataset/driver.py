"""The build on Ray: one Ray task per problem, resumable, with progress, a time limit per
problem and a record of every run.

Everything that can be refused is checked before anything is written (the problems, the settings
against those of the folder's earlier runs, a given heatmap's kind and robot, the CPUs a problem
asks for), so a refused build leaves the folder as it was. Then the folder is locked, this run's
entry appended to ``build.json``, the robot-only heatmaps built, and the problems not finished yet
run.

Without an address a local Ray is started in this process (every CPU this process may use, no
dashboard, a worker started when a task needs one) on the loopback address:
``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` before Ray is imported (the variable Ray's cluster docs
name; off, Ray's node address is the loopback) and
``ray.init``'s documented ``_node_ip_address`` (which alone Ray turns into the machine's address
on Linux); the node's address is checked after the start. With ``ray_address`` (``HOST:PORT`` of
a ``ray start --head``) the build runs on that cluster, whose nodes must run this same
installation.

A task holds ``cpus_per_problem`` Ray CPUs and runs with its threads capped at them
(``dataset.threads``). Tasks are submitted as slots free up (per node, its CPUs //
``cpus_per_problem``), so a task starts when it is submitted and its clock
(``problem_timeout_s``) starts then; a task still running at its limit is cancelled (its worker
killed) and recorded as ``timeout``. A task whose worker process dies is retried by Ray
(``max_retries``); what Ray reports after that is recorded as what it is (``classify``). Results
are written as they arrive (``dataset.store``); a stopped build (Ctrl-C or SIGTERM: its entry says
``interrupted``; kill -9: it stays ``running``) resumes when run again with the same settings and
``--out``. A Ctrl-C is remembered as well as raised (``_ctrl_c_kept``) and the loop stops on the
memory: Ray's waits run signal handlers themselves, from C++. A build started with SIGINT ignored
(a shell's background job, and what it starts) ignores Ctrl-C as any program then does; SIGTERM
stops it.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import logging
import os
import pathlib
import signal
import sys
import threading
import time

from advocc_ros.dataset import machines, store
from advocc_ros.dataset.heatmaps import (file_sha256, heatmap_path, heatmap_settings, load_given,
                                         robot_heatmaps)
from advocc_ros.dataset.job import (ALONE_CPUS, OUTCOMES, BuildConfig, posed, problem_input,
                                    run_problem)
from advocc_ros.dataset.problems import DatasetError, Problem, discover, select
from advocc_ros.dataset.threads import inherited, task_threads, thread_caps
from advocc_ros.evaluation import provenance
from advocc_ros.limits import available_cpus

log = logging.getLogger(__name__)

LOOPBACK_ENV = 'RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER'
"""0 before Ray is imported: a local Ray takes the loopback address as its node's and binds its
servers to it; otherwise it listens on every interface."""
LOOPBACK = '127.0.0.1'
HEARTBEAT_S = 30.0
"""Longest wait for a result before the progress shows again [s]."""
_SIGINT_SEEN = threading.Event()


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """How the build is distributed and bounded (none of it changes a finished problem's
    result, except that timing figures are faithful only with ``job.ALONE_CPUS``)."""

    ray_address: str | None = None
    """``HOST:PORT`` of a running Ray cluster; None: a local Ray in this process."""
    max_retries: int = 3
    """Times Ray runs a problem again after its worker process died."""
    cpus_per_problem: float = 2.0
    """Ray CPUs a problem holds; its threads are capped at them (2: its victims' times share
    no CPU with the build, ``job.ALONE_CPUS``)."""
    problem_timeout_s: float = 3600.0
    """A problem still running this long after it started is cancelled: ``timeout`` [s] (a
    problem of the default settings takes minutes)."""
    heatmap_samples: int = 15_000
    """Valid samples of the robot-only heatmap (``HeatmapConfig.samples``' default)."""
    heatmap_seed: int = 0
    heatmap_file: str | None = None
    """A robot-only heatmap file to use instead of building one."""


@dataclasses.dataclass(frozen=True)
class Selection:
    """Which problems: the folder, families (None: all), split and the seeded limit (per
    family, counted over the problems the goal form poses when ``problems`` is given
    ``posable``)."""

    root: str
    families: tuple[str, ...] | None = None
    split: str = 'all'
    limit: int | None = None
    seed: int = 0

    def problems(self, posable=None) -> list[Problem]:
        return select(discover(self.root, list(self.families or ())), self.split, self.limit,
                      self.seed, posable)


class Cluster:
    """Ray for one or more builds of the same ``RunConfig``: connected or started when the first
    build has work, shut down once at the end (``--goal-form both`` starts Ray once)."""

    def __init__(self, run: RunConfig):
        self.run = run
        self._ray = None

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc) -> None:
        if self._ray is not None:
            self._ray.shutdown()
            self._ray = None

    def ray(self):
        if self._ray is None:
            self._ray = _ray(self.run)
        return self._ray


def build(selection: Selection, out: str | pathlib.Path, config: BuildConfig,
          run: RunConfig = RunConfig(), echo=None, cluster: Cluster | None = None) -> dict:
    """Build (or resume) the data set of ``selection`` into ``out``; this run's entry of
    ``build.json`` with the ``summary`` of the selection. Progress goes to stderr. Without
    ``cluster``, Ray is started (or connected) for this build alone."""
    from advocc_ros.dataset.summary import write_summary

    if cluster is None:
        with Cluster(run) as own:
            return build(selection, out, config, run, echo, own)
    echo = echo or (lambda text: print(text, file=sys.stderr, flush=True))
    out = pathlib.Path(out)
    problems, todo, settings, given, hashes, scenes = _checked(selection, out, config, run)
    out.mkdir(parents=True, exist_ok=True)
    with store.locked(out):
        slots = _slots(cluster.ray(), run.cpus_per_problem) if todo else 0  # before any record
        record = store.check_settings(out, settings) or {
            'format': store.BUILD_FORMAT, 'version': store.BUILD_VERSION, 'settings': settings,
            'runs': []}
        entry = _entry(selection, problems, todo, run)
        record['runs'].append(entry)
        store.write_build(out, record)
        echo(f'advocc dataset: {len(problems)} problems, {len(problems) - len(todo)} already '
             f'finished in {out}, {len(todo)} to build')
        found = [r for r, _ in store.records(out, [p.key for p in problems])] if todo else []
        note = machines.speed_note(found, entry['speed_checks_per_s'], config.time_s)
        if note:
            echo(note)
        t0 = time.perf_counter()
        try:
            if todo:
                heatmaps = robot_heatmaps(scenes, out, run.heatmap_samples, run.heatmap_seed,
                                          given, workers=available_cpus(), echo=echo)
                entry['heatmaps'] = {h: settings['heatmap'].get('sha256') or file_sha256(
                    heatmap_path(out, h)) for h in heatmaps}
                with _ctrl_c_kept():
                    _run(todo, out, config, cluster, slots, echo, entry, hashes, heatmaps)
            entry['status'] = 'finished'
        except BaseException as exc:
            stopped = isinstance(exc, (KeyboardInterrupt, SystemExit))
            entry.update(status='interrupted' if stopped else 'failed',
                         reason=f'{type(exc).__name__}: {exc}'.strip(': '))
            raise
        finally:
            entry.update(finished=provenance.now(), wall_s=round(time.perf_counter() - t0, 3),
                         load_end=provenance.load())
            store.write_build(out, record)
    return dict(entry, summary=write_summary(out, [p.key for p in problems]))


def _checked(selection: Selection, out: pathlib.Path, config: BuildConfig, run: RunConfig):
    """Everything a build may refuse, checked with nothing written: the problems, the problems
    left to do, the settings, the given heatmap (None: built), and the robots of the problems
    left (``_robots``)."""
    problems = selection.problems(posable_in(config))
    if not problems:
        raise DatasetError(f'{selection.root}: no problems in split {selection.split!r} of '
                           f'families {list(selection.families or []) or "all"}')
    if run.ray_address is None and run.cpus_per_problem > available_cpus():
        raise DatasetError(f'--cpus-per-problem {run.cpus_per_problem:g}: this process may use '
                           f'{available_cpus()} CPU(s); give at most that (and say so with '
                           'the figures: the victims then share their CPUs)')
    given = load_given(run.heatmap_file) if run.heatmap_file else None
    settings = json.loads(json.dumps({  # as build.json reads back
        'build': config.to_json(), 'heatmap': heatmap_settings(
            run.heatmap_samples, run.heatmap_seed,
            file_sha256(run.heatmap_file) if given is not None else None)}))
    store.check_settings(out, settings)
    todo = interleaved([p for p in problems if store.finished(
        out, p.family, p.name, run.problem_timeout_s) is None])
    hashes, scenes = _robots(todo, config.goal_tol)
    other = sorted(k for k, h in hashes.items()
                   if given is not None and h != given.meta.get('robot_hash'))
    if other:  # only a given file can miss a robot
        raise DatasetError(f'{run.heatmap_file}: built for robot '
                           f'{given.meta.get("robot_hash")}, not the robot of {other[0]} '
                           f'({hashes[other[0]]}) and {len(other) - 1} more problem(s)')
    return problems, todo, settings, given, hashes, scenes


def posable_in(config: BuildConfig):
    """Whether the goal form of ``config`` poses a problem: it loads and its task check passes
    (``job.posed``); the job of a problem that does not refuses it and says why."""
    from advocc_ros.formats.mbm_scene import load_any_scene

    def posable(p: Problem) -> bool:
        try:
            scene = load_any_scene(p.scene, p.request, config.goal_tol, config.goal_form)
            return scene.start is not None and scene.goal is not None and posed(scene)[2] is None
        except Exception as exc:  # the job says why, as the problem's outcome
            log.info('%s does not load here: %s', p.key, exc)
            return False
    return posable


def _entry(selection: Selection, problems: list[Problem], todo: list[Problem],
           run: RunConfig) -> dict:
    """This run's entry of ``build.json`` as it starts."""
    alone = run.cpus_per_problem >= ALONE_CPUS
    return {'selection': {**dataclasses.asdict(selection),
                          'root': str(pathlib.Path(selection.root).resolve()),
                          'problems': [p.key for p in problems]},
            'run': dataclasses.asdict(run), 'provenance': provenance.record(),
            'speed_checks_per_s': machines.probe(machines.RUN_PROBES), 'started': provenance.now(),
            'status': 'running',
            'resumed': len(problems) - len(todo), 'todo': len(todo),
            'timing': {'cpus_per_problem': run.cpus_per_problem,
                       'threads_per_problem': task_threads(run.cpus_per_problem),
                       'victims_cpus_alone': alone,
                       'note': (f'each problem held {run.cpus_per_problem:g} CPUs: its victims '
                                'shared no CPU with the build' if alone else
                                f'each problem held {run.cpus_per_problem:g} CPU(s) (fewer than '
                                f'{ALONE_CPUS}): its victims may have shared their CPUs with '
                                'other problems; time figures are not faithful')}}


def interleaved(problems: list[Problem]) -> list[Problem]:
    """``problems`` taken one family at a time in turn (each family in its own order), so that
    a build stopped part-way has built about as many problems of every family."""
    families: dict[str, list[Problem]] = {}
    for p in problems:
        families.setdefault(p.family, []).append(p)
    queues = list(families.values())
    return [q[i] for i in range(max(map(len, queues), default=0)) for q in queues if i < len(q)]


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


LOCAL_RAY_CONFIG = {'enable_worker_prestart': False}
"""No worker a CPU at start-up: a task holds ``cpus_per_problem`` CPUs (2 by default), so most
prestarted workers would only idle (docs/performance.md)."""


def _ray(run: RunConfig):
    """Ray, connected to ``run.ray_address`` or started here on the loopback address."""
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    if run.ray_address is None:
        os.environ[LOOPBACK_ENV] = '0'  # read when Ray is imported (see the module docstring)
    import ray

    if run.ray_address is not None:
        try:
            ray.init(address=run.ray_address, log_to_driver=False, namespace='advocc_dataset')
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise DatasetError(f'--ray-address {run.ray_address}: cannot connect ({exc})') \
                from None
        return ray
    with inherited(thread_caps(run.cpus_per_problem)):  # by the local Ray and its workers
        ray.init(address='local', num_cpus=available_cpus(), include_dashboard=False,
                 log_to_driver=False, namespace='advocc_dataset', _node_ip_address=LOOPBACK,
                 _system_config=LOCAL_RAY_CONFIG)
    addresses = {n.get('NodeManagerAddress') for n in ray.nodes()}
    if addresses != {LOOPBACK}:
        ray.shutdown()
        raise DatasetError(f'the local Ray took the address {", ".join(map(str, addresses))}, '
                           f'not the loopback ({LOOPBACK}): Ray was imported in this process '
                           f'before the build without {LOOPBACK_ENV}=0; run the build in a '
                           'process of its own (advocc dataset build)')
    return ray


def _slots(ray, cpus: float) -> int:
    """Problems the cluster runs at once: per alive node, its CPUs // ``cpus``; a
    ``DatasetError`` when no node has ``cpus`` CPUs (the tasks would wait forever)."""
    nodes = [n for n in ray.nodes() if n.get('Alive')]
    slots = sum(int(n.get('Resources', {}).get('CPU', 0) // cpus) for n in nodes)
    if slots < 1:
        biggest = max((n.get('Resources', {}).get('CPU', 0) for n in nodes), default=0)
        raise DatasetError(f'--cpus-per-problem {cpus:g}: no node of the Ray cluster has that '
                           f'many CPUs (the largest has {biggest:g})')
    return slots


def _run(todo: list[Problem], out: pathlib.Path, config: BuildConfig, cluster: Cluster,
         slots: int, echo, entry: dict, hashes: dict, heatmaps: dict) -> None:
    """Run ``todo`` on ``cluster``, ``slots`` problems at once, writing each result as it
    arrives; ``entry['counts']`` counts the outcomes so far."""
    from advocc_ros.progress import progress_bar

    run = cluster.run
    ray = cluster.ray()
    entry['counts'] = counts = {}
    pending: dict = {}
    bar = None
    try:
        node = ray.get_runtime_context().get_node_id()
        entry['cluster'] = {'address': run.ray_address or 'local', 'driver_node': node,
                            'resources': ray.cluster_resources(),
                            'nodes': len([n for n in ray.nodes() if n.get('Alive')])}
        task = _task(ray, run)
        refs = {h: ray.put(hm) for h, hm in heatmaps.items()}
        queue = collections.deque(todo)
        bar = progress_bar(len(todo), 'dataset', 'problem', file=sys.stderr)
        t0 = time.monotonic()
        while queue or pending:
            while queue and len(pending) < slots:
                p = queue.popleft()
                log_to = {'path': str(store.log_path(out, p.family, p.name).resolve()),
                          'node': node}
                ref = task.remote(problem_input(p), refs.get(hashes.get(p.key)), config, log_to)
                pending[ref] = (p, time.monotonic(), provenance.now())
            results = _next_results(ray, pending, run)
            if _SIGINT_SEEN.is_set():  # whatever swallowed its KeyboardInterrupt
                raise KeyboardInterrupt
            for result in results:
                _save(out, result, counts, bar)
            left = len(pending) + len(queue)
            done = len(todo) - left
            eta = _duration((time.monotonic() - t0) / done * left) if done else '?'
            bar.set_postfix(done=done, left=left, eta=eta, **counts)
            bar.update(len(results))  # 0: a line in a log even while no problem finishes
    finally:
        if bar is not None:
            bar.close()
        for ref in pending:  # stopped: nothing of this build keeps running on a cluster
            try:
                ray.cancel(ref, force=True)
            except Exception:  # already finished or its node is gone
                pass


@contextlib.contextmanager
def _ctrl_c_kept():
    """SIGINT raises ``KeyboardInterrupt`` as Python's own handler does, and is remembered in
    ``_SIGINT_SEEN``; only over Python's handler in the main thread (an inherited SIG_IGN, a
    background job's, stays)."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    _SIGINT_SEEN.clear()
    old = signal.signal(signal.SIGINT, _remember_and_raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _remember_and_raise(signum, frame):
    _SIGINT_SEEN.set()
    raise KeyboardInterrupt


def _task(ray, run: RunConfig):
    """``run_problem`` as a Ray task: ``cpus_per_problem`` CPUs, its threads capped at them
    (``dataset.threads``: in its worker's environment from the start, before a BLAS
    reads it), retried after a worker death, never after an exception (the job has none)."""
    env = {} if run.ray_address is None else \
        {'runtime_env': {'env_vars': thread_caps(run.cpus_per_problem)}}
    return ray.remote(num_cpus=run.cpus_per_problem, max_retries=run.max_retries,
                      retry_exceptions=False, **env)(run_problem)


def _next_results(ray, pending: dict, run: RunConfig) -> list[dict]:
    """The results that arrive within the next heartbeat (at most until the nearest time
    limit), and a ``timeout`` result for every task past its limit (cancelled: its worker is
    killed). Takes them out of ``pending``."""
    nearest = min(t + run.problem_timeout_s for _, t, _ in pending.values())
    ready = _wait_one(ray, list(pending), min(HEARTBEAT_S, nearest - time.monotonic()))
    results = [_result(ray, ref, pending.pop(ref), run) for ref in ready]
    for ref, (p, t, started) in list(pending.items()):
        if time.monotonic() - t < run.problem_timeout_s:
            continue
        if ray.wait([ref], timeout=0)[0]:  # it did finish, just now
            results.append(_result(ray, ref, pending.pop(ref), run))
            continue
        ray.cancel(ref, force=True)
        del pending[ref]
        results.append(failed(p, 'timeout', f'still running after {run.problem_timeout_s:g} s '
                              '(--problem-timeout): cancelled, its worker killed', run,
                              started))
    return results


def _wait_one(ray, refs: list, timeout_s: float) -> list:
    """``ray.wait`` for one of ``refs`` within ``timeout_s``, in steps of at most 1 s that end
    early on a remembered Ctrl-C (``_ctrl_c_kept``)."""
    deadline = time.monotonic() + max(0.0, timeout_s)
    while True:
        ready, _ = ray.wait(refs, num_returns=1,
                            timeout=max(0.0, min(1.0, deadline - time.monotonic())))
        if ready or _SIGINT_SEEN.is_set() or time.monotonic() >= deadline:
            return ready


def _result(ray, ref, task: tuple, run: RunConfig) -> dict:
    """The result of a finished task (``pending``'s ``(problem, clock, started)``), or what the
    driver records when Ray returned an error instead (``classify``)."""
    p, _, started = task
    try:
        return ray.get(ref)
    except ray.exceptions.RayError as exc:
        return failed(p, *classify(exc, run.max_retries), run, started)


def _save(out: pathlib.Path, result: dict, counts: dict, bar) -> None:
    store.save_result(out, result)
    record = result['record']
    counts[record['outcome']] = counts.get(record['outcome'], 0) + 1
    if record['outcome'] != 'built':
        bar.write(f'{record["family"]}/{record["problem"]}: {record["outcome"]}: '
                  f'{record["reason"]}')
    if result.get('driver_note'):
        store.append_log(out, record['family'], record['problem'], result['driver_note'])


def classify(exc: Exception, max_retries: int) -> tuple[str, str]:
    """(outcome, reason) of a task for which Ray returned ``exc`` instead of a result (after
    its retries): ``memory``, ``cancelled``, ``crashed`` or ``error`` (``job.OUTCOMES``)."""
    import ray.exceptions as rx

    def first_line(e: BaseException) -> str:
        lines = [line for line in str(e).splitlines() if line.strip()]
        return f'{type(e).__name__}: {lines[0].strip()}' if lines else type(e).__name__

    if isinstance(exc, rx.OutOfMemoryError):
        return 'memory', f'killed by Ray\'s memory monitor, the node ran low on memory ' \
                         f'({first_line(exc)})'
    if isinstance(exc, rx.TaskCancelledError):
        return 'cancelled', f'cancelled outside this build ({first_line(exc)})'
    if isinstance(exc, (rx.WorkerCrashedError, rx.NodeDiedError, rx.LocalRayletDiedError)):
        return 'crashed', f'its worker process or node died {max_retries + 1} time(s) ' \
                          f'({first_line(exc)})'
    if isinstance(exc, rx.RayTaskError):  # the job never raises: this is Ray's side of it
        cause = getattr(exc, 'cause', None) or exc
        return 'error', f'the task failed outside the job, e.g. its result did not ' \
                        f'serialise ({first_line(cause)})'
    return 'error', f'Ray: {first_line(exc)}'


def failed(p: Problem, outcome: str, reason: str, run: RunConfig, started: str) -> dict:
    """The result the driver records for a task that returned none; its provenance is the
    driver's (``by: driver``: the worker's host is not known)."""
    if outcome not in OUTCOMES:
        raise ValueError(f'outcome {outcome!r}: not one of {OUTCOMES}')
    record = {'family': p.family, 'problem': p.name, 'split': p.split, 'outcome': outcome,
              'reason': reason,
              'provenance': dict(provenance.record(), by='driver', started=started,
                                 finished=provenance.now(), cpus=run.cpus_per_problem,
                                 victims_cpus_alone=None)}
    if outcome == 'timeout':
        record['timeout_s'] = run.problem_timeout_s
    note = f'--- the driver, {provenance.now()}: {outcome}: {reason}'
    return {'record': record, 'hardness': None, 'files': {}, 'log': None, 'driver_note': note}


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f'{seconds // 3600}h{seconds % 3600 // 60:02d}m'
    return f'{seconds // 60}m{seconds % 60:02d}s'


__all__ = ['HEARTBEAT_S', 'LOOPBACK_ENV', 'RunConfig', 'Selection', 'build', 'classify', 'failed',
           'interleaved']
