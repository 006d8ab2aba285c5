"""One problem of the data set, start to end: what a Ray task runs, with no ROS and no files
of the driver's machine.

The job gets the problem's two files as bytes (a worker on another machine has no access to the
driver's folder) and the robot-only heatmap, and returns everything as data; the driver writes
it (``dataset.store``). Steps: load the problem; the task check (``model.task_check``: a task no
planner can solve is refused, with its reason); then per budget the ``task`` attack under the
``solvable`` goal policy (``attack.edges.attack_task``, which finds the task's witness first:
no witness, no certified attack, outcome ``no_witness``); the continuous certificate's verdict
(``AttackResult.solvable``), checked again on the exported problem as ``advocc export`` does;
the victims on the unattacked problem and on every certified attacked one
(``evaluation.runner.evaluate_planner``, as ``advocc evaluate`` runs them); and the attacked
problems in MotionBenchMaker's format (``formats.mbm_export``).

Every problem ends with an outcome (``OUTCOMES``), never an exception: a malformed file is
``refused`` with the parser's reason, an unexpected exception is ``error`` with its message. The
record names its making (``provenance``: commit, host, CPU, the CPUs and threads the task held,
load, versions, start and end), and the task's output goes to a log (``task_log``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import pathlib
import socket
import sys
import tempfile
import time
import traceback
from typing import Any, Iterator

log = logging.getLogger(__name__)

OUTCOMES = ('built', 'uncertified', 'no_witness', 'refused', 'timeout', 'memory', 'crashed',
            'cancelled', 'error')
"""How a problem ended: ``built`` (at least one budget's attack certified, exported and
evaluated), ``uncertified`` (the witness was found but no budget's attack was certified),
``no_witness`` (no path on the unattacked problem: nothing can be certified), ``refused`` (a
malformed problem or one the task check refuses, with the reason); then what the driver records
when no result came back: ``timeout`` (still running after ``--problem-timeout``: cancelled),
``memory`` (killed by Ray's memory monitor), ``crashed`` (its worker process or node died more
than ``--max-retries`` times), ``cancelled`` (cancelled by someone else) and ``error`` (an
exception, or a task that failed outside the job, e.g. a result that did not serialise)."""
FINAL_OUTCOMES = OUTCOMES[:4]
"""Outcomes a resumed build keeps; ``timeout`` is kept when the limit it hit is at least the
resumed build's, the rest are redone."""
ALONE_CPUS = 2
"""Ray CPUs a problem holds for its victims' times not to share a CPU with the build: a problem
runs two processes (its job, and the planner process of a victim or of the witness search), and
with its threads capped at the CPUs it holds, no other problem's work lands on them."""
HARDNESS_FORMAT = 'advocc_dataset_hardness'
PSR_HARD = 0.2
"""A victim counts as beaten on a problem when its PSR is at most this (the audit's line)."""
MAX_LOG_BYTES = 1 << 20
"""The tail of a task's log returned to the driver when the task ran on another node."""


@dataclasses.dataclass(frozen=True)
class BuildConfig:
    """What every problem of a build is run with (the settings a resumed build must share)."""

    budgets: tuple[int, ...] = (5, 10)
    """Boxes M of the attacks: each budget is attacked on its own."""
    victims: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1', 'mplib')
    """Planners measured (OMPL ids, outside victims such as ``mplib``, ``trajopt``)."""
    trials: int = 20
    """Plan requests per victim and budget (and on the unattacked problem)."""
    time_s: float = 5.0
    """Budget per plan request [s]; also the ``allowed_planning_time`` of the exported
    requests."""
    seed: int = 0
    """Attack seed; trial k of every victim uses seed ``seed + k``."""
    task_options: tuple[tuple[str, Any], ...] = (('exit_rays', 65536), ('exit_rounds', 3),
                                                 ('pocket_samples', 4096), ('pocket_tier', 1),
                                                 ('corridor_routes', 1024))
    """``TaskOptions`` of the attack that differ from their defaults (key, value). The data
    set's default closes a joint goal's pocket first (``pocket_tier``), sampled 16 times as
    densely as the attack's own default (``pocket_samples``), and keeps the witness whose boxes
    leave the goal fewest free RRT steps (``exit_rays``, ``attack.exits``), then closes the
    steps left free in up to three rounds (``exit_rounds``) together with the free ones of 1,024
    paths beside the witness (``corridor_routes``), all chosen on the train split
    (docs/results/mbm_joint_train)."""
    goal_tol: str | None = None
    """Goal tolerance around a joint goal in the region form (``--goal-tol``; None: the
    default region)."""
    goal_form: str = 'joint'
    """How a request's joint goal is posed (``model.goal.GOAL_FORMS``): ``joint``, the
    configuration itself; ``region``, the paper's region around its hand pose."""
    victim_margin_m: float = 0.004
    """``AttackConfig.victim_margin_m`` of the attacks, chosen on the train split for MPlib's
    own collision check (FCL) to accept the witnesses (docs/results/mbm_joint_train: it calls 2
    of 6 blocked at 0, 1 of 12 at 0.004 m); the attack's own default is 0."""

    escape_rays: int = 100_000
    """In the ``joint`` form, the RRT steps from the goal each certified attack's goal escape
    share is measured on (``attack.exits.escape_share``, at the victims' step): p = 1e-5 is
    AORRTC's PSR of 0.2 in 5 s; 0: not measured (and not in the settings, as before it was
    measured)."""

    def to_json(self) -> dict:
        return {'budgets': list(self.budgets), 'victims': list(self.victims),
                'trials': self.trials, 'time_s': self.time_s, 'seed': self.seed,
                'task_options': dict(self.task_options), 'goal_tol': self.goal_tol,
                'goal_form': self.goal_form, 'victim_margin_m': self.victim_margin_m,
                'method': 'task', 'goal_policy': 'solvable',
                **({'escape_rays': self.escape_rays} if self.escape_rays else {})}


def problem_input(problem) -> dict:
    """What a job needs of ``problem`` (``dataset.problems.Problem``): names and file bytes
    (None for a file that cannot be read: the job refuses the problem and says why)."""
    def read(path: pathlib.Path) -> bytes | str:
        try:
            return path.read_bytes()
        except OSError as exc:
            return f'{path}: cannot read ({exc.strerror or exc})'
    return {'family': problem.family, 'index': problem.index, 'split': problem.split,
            'scene_name': problem.scene.name, 'scene': read(problem.scene),
            'request_name': problem.request.name, 'request': read(problem.request)}


def _ray_context() -> tuple[str | None, float | None]:
    """The Ray node this job runs on and the CPUs its task holds (None, None outside Ray)."""
    ray = sys.modules.get('ray')
    if ray is None or not ray.is_initialized():
        return None, None
    context = ray.get_runtime_context()
    return context.get_node_id(), context.get_assigned_resources().get('CPU')


def provenance(cpus: float | None, node: str | None) -> dict:
    """What makes this record (``evaluation.provenance.record``: commit, dirty flag, host,
    CPU, cores, load, versions), with the Ray CPUs the task holds (``cpus``), the threads its
    process may run (``limits.worker_threads``: its C++ pools and the kernels' parallel loops),
    whether its victims had their CPUs alone (``ALONE_CPUS``), its node and process."""
    from advocc_ros.limits import worker_threads
    from advocc_ros.evaluation.provenance import record

    return dict(record(), cpus=cpus, threads=worker_threads(),
                victims_cpus_alone=None if cpus is None else cpus >= ALONE_CPUS,
                node=node, pid=os.getpid())


@contextlib.contextmanager
def task_log(log_to: dict | None, title: str) -> Iterator[dict]:
    """This task's output in a log: file descriptors 1 and 2 (which the planner processes it
    starts inherit) and the ``advocc_ros`` loggers at INFO. ``log_to``: ``{'path', 'node'}``
    from the driver; on the driver's node the log is ``path`` itself (appended to, and there
    while the task runs, so a task that hangs or dies leaves its log), on another node a
    temporary file whose last ``MAX_LOG_BYTES`` the yielded dict gets as ``text``. None: no
    log."""
    out: dict = {'text': None}
    if log_to is None:
        yield out
        return
    local = log_to.get('node') is not None and _ray_context()[0] == log_to['node']
    if local:
        path = pathlib.Path(log_to['path'])
        path.parent.mkdir(parents=True, exist_ok=True)
    else:
        fd, name = tempfile.mkstemp(prefix='advocc_task_', suffix='.log')
        os.close(fd)
        path = pathlib.Path(name)
    from advocc_ros.evaluation.provenance import now

    with open(path, 'ab') as handle:
        handle.write(f'--- {title}: {socket.gethostname()} pid {os.getpid()}, {now()}\n'
                     .encode())
        handle.flush()
        with _redirected(handle.fileno()), _logging_to(path):
            try:
                yield out
            finally:
                print(f'--- {title}: ended {now()}', flush=True)
    if not local:
        with open(path, 'rb') as handle:
            handle.seek(max(0, path.stat().st_size - MAX_LOG_BYTES))
            out['text'] = handle.read().decode('utf-8', errors='replace')
        path.unlink(missing_ok=True)


@contextlib.contextmanager
def _redirected(fd: int) -> Iterator[None]:
    """File descriptors 1 and 2 of this process onto ``fd`` for a while, and ``sys.stdout``
    and ``sys.stderr`` onto them (whatever they were: a test runner's capture, say)."""
    streams = sys.stdout, sys.stderr
    for stream in streams:
        stream.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        sys.stdout, sys.stderr = (open(n, 'w', encoding='utf-8', errors='replace',
                                       buffering=1, closefd=False) for n in (1, 2))
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            if stream not in streams:
                stream.close()  # flushes; the descriptor stays open (closefd=False)
        sys.stdout, sys.stderr = streams
        for target, copy in zip((1, 2), saved):
            os.dup2(copy, target)
            os.close(copy)


@contextlib.contextmanager
def _logging_to(path: pathlib.Path) -> Iterator[None]:
    """The ``advocc_ros`` loggers at INFO into ``path`` (only there) for a while."""
    logger = logging.getLogger('advocc_ros')
    handler = logging.FileHandler(path, mode='a', encoding='utf-8')
    handler.setFormatter(logging.Formatter('%(asctime)s %(levelname)s %(name)s: %(message)s'))
    level, propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
        handler.close()


def run_problem(problem: dict, heatmap, config: BuildConfig, log_to: dict | None = None
                ) -> dict:
    """The result of one problem (``problem_input``): ``record`` (outcome, reason, times,
    ``provenance``), ``hardness`` (None unless evaluated), ``files`` (relative path -> YAML
    data) and ``log`` (the task's log text when ``task_log`` could not write it where the
    driver reads it, else None). Never raises."""
    from advocc_ros.dataset.machines import probe
    from advocc_ros.evaluation.provenance import load, now

    t0 = time.perf_counter()
    key = f'{problem["family"]}/{problem["index"]:04d}'
    record = {'family': problem['family'], 'problem': f'{problem["index"]:04d}',
              'split': problem['split']}
    started, load_start = now(), load()
    files: dict[str, Any] = {}
    with task_log(log_to, key) as captured:
        (node, cpus), checks_per_s = _ray_context(), probe()  # the speed before the work
        log.info('%s: started (%s CPUs, %s validity checks/s)', key, cpus, checks_per_s)
        try:
            outcome, reason, hardness = _run(problem, heatmap, config, files, record)
        except Exception as exc:  # any bug or backend failure becomes this problem's record
            log.exception('problem %s failed', key)
            outcome, reason, hardness, files = 'error', f'{type(exc).__name__}: {exc}', None, {}
            record['traceback'] = traceback.format_exc(limit=8)
        log.info('%s: %s %s', key, outcome, reason)
    made = provenance(cpus, node)  # after the work: the threads it did run with
    record.update(outcome=outcome, reason=reason, total_s=round(time.perf_counter() - t0, 3),
                  provenance=dict(made, load=load_start, load_end=made['load'],
                                  speed_checks_per_s=checks_per_s, started=started,
                                  finished=now()))
    return {'record': record, 'hardness': hardness, 'files': files, 'log': captured['text']}


def _load(problem: dict, goal_tol, goal_form: str):
    """The problem's scene, or the reason it is refused."""
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.robot import RobotError

    for key in ('scene', 'request'):
        if isinstance(problem[key], str):
            return None, problem[key]
    with tempfile.TemporaryDirectory(prefix='advocc_problem_') as tmp:
        scene_path = pathlib.Path(tmp) / pathlib.Path(problem['scene_name']).name
        request_path = pathlib.Path(tmp) / pathlib.Path(problem['request_name']).name
        scene_path.write_bytes(problem['scene'])
        request_path.write_bytes(problem['request'])
        try:
            scene = load_any_scene(scene_path, request_path, goal_tol, goal_form)
        except (SceneError, RobotError, ValueError) as exc:
            return None, f'malformed problem: {str(exc).replace(tmp + "/", "")}'
    if scene.start is None or scene.goal is None:
        return None, 'malformed problem: no start state or no goal'
    return scene, None


def posed(scene):
    """(robot, start configuration, None) of a loaded problem whose task the goal form poses,
    or (robot, start, reason) when the task check refuses it (a start or joint goal outside
    the limits or in collision: no solution to certify)."""
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.task_check import check_task

    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    fault = check_task(robot, scene.objects, q_init, scene.goal)
    return robot, q_init, None if fault is None else f'the task is refused: {fault.message}'


def _run(problem: dict, heatmap, config: BuildConfig, files: dict, record: dict):
    """(outcome, reason, hardness) of the steps of the module docstring; fills ``files``
    with the exported problems and ``record`` with the steps' times."""
    from advocc_ros.attack import AttackConfig, AttackStatus
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.attack.exits import escape_share
    from advocc_ros.attack.task import task_options
    from advocc_ros.planning.victims import VictimConfig

    t = time.perf_counter()
    scene, why = _load(problem, config.goal_tol, config.goal_form)
    if scene is None:
        return 'refused', why, None
    robot, q_init, why = posed(scene)
    if why is not None:
        return 'refused', why, None
    if heatmap is None or heatmap.meta.get('robot_hash') != robot.hash:
        return 'error', f'no robot-only heatmap for this problem\'s robot ({robot.hash})', None
    record['load_s'] = round(time.perf_counter() - t, 3)
    options = task_options(dict(config.task_options)) if config.task_options else None
    cfg = AttackConfig(goal_policy='solvable', victim_margin_m=config.victim_margin_m)
    attacks, scenes = {}, {}
    for budget in config.budgets:
        log.info('attack at M=%d', budget)
        t = time.perf_counter()
        result = attack_task(heatmap, robot, scene.objects, q_init, scene.goal, budget, 'task',
                             cfg, seed=config.seed, method_options=options)
        wall_s = time.perf_counter() - t
        if result.status == AttackStatus.NO_WITNESS:
            record['attack_s'] = round(wall_s, 3)
            return 'no_witness', result.message, None
        entry, attacked = _attack_entry(result, scene, robot, q_init, wall_s)
        if attacked is not None and scene.goal.is_joint and config.escape_rays:
            entry['goal_escape'] = escape_share(
                robot, attacked.shapes, scene.goal.configuration(robot.joint_names),
                config.escape_rays, VictimConfig().check_step_rad)
        if attacked is not None and 'mplib' in config.victims:
            entry['witness_checks'] = {'mplib': mplib_witness_check(
                attacked, robot, q_init, result.witness)}
        if attacked is not None:
            folder = f'm{budget}'
            entry['exported'] = folder
            files.update(_export(folder, problem['index'], attacked, robot, result.witness,
                                 config.time_s))
            scenes[budget] = attacked
        attacks[str(budget)] = entry
    record['attack_s'] = round(sum(a['wall_s'] for a in attacks.values()), 3)
    if not scenes:
        reasons = '; '.join(f'M={b}: {a["certificate"]} ({a["message"]})'
                            for b, a in attacks.items())
        return 'uncertified', f'no attack was certified: {reasons}', _hardness(
            problem, config, attacks, {})
    log.info('victims %s on the unattacked problem and at M=%s', ','.join(config.victims),
             ','.join(map(str, scenes)))
    t = time.perf_counter()
    unattacked = _evaluate(scene, config, attacks, scenes)
    record['evaluate_s'] = round(time.perf_counter() - t, 3)
    return 'built', '', _hardness(problem, config, attacks, unattacked)


WITNESS_CHECK_STEP_RAD = 0.002
"""Joint-space step at which a victim's own checker is asked about the witness [rad]."""


def mplib_witness_check(scene, robot, q_init, witness, victim=None) -> dict:
    """What MPlib's own collision check (FCL on its model) says of the witness on ``scene``
    (the attacked problem): its states every ``WITNESS_CHECK_STEP_RAD``, how many collide
    and whether it accepts the path. A corridor a victim's checker calls closed is no
    solution for that victim. ``victim``: an MPlib victim to ask (kept open; default: one of
    its own, closed after)."""
    import numpy as np

    from advocc_ros.planning.victims import VictimConfig, make_victim
    from advocc_ros.planning.victims.base import Task, densify

    Q = densify(witness.configurations(robot), WITNESS_CHECK_STEP_RAD)
    own = victim is None
    victim = make_victim('mplib', VictimConfig()) if own else victim
    try:
        task = Task(scene, q_init, scene.goal)
        colliding = np.concatenate([victim.check(task, Q[i:i + 100])
                                    for i in range(0, len(Q), 100)])
    finally:
        if own:
            victim.close()
    first = int(np.argmax(colliding)) if colliding.any() else -1
    return {'states': len(Q), 'colliding': int(colliding.sum()), 'first_colliding': first,
            'accepted': not bool(colliding.any())}


EXIT_STATS = ('goal_exit_rays', 'goal_exits_unattacked', 'goal_exits', 'witness_exits',
              'goal_exits_by_round', 'goal_exit_draws_kept', 'routes', 'routes_cut',
              'corridor_routes', 'corridor_routes_cut')
"""The attack's statistics of ``attack.exits`` a hardness file keeps (when it chose by them,
or cut the routes beside the witness)."""


def _attack_entry(result, scene, robot, q_init, wall_s: float):
    """The hardness file's record of one attack, and the attacked scene when its witness is
    certified with the boxes (else None)."""
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.planning.witness import certify

    verdict = result.solvable
    entry = {'status': result.status.value, 'message': result.message,
             'goal_form': result.goal_form,
             'boxes': len(result.obstacles), 'wall_s': round(wall_s, 3),
             'compute_ms': round(result.compute_s * 1e3, 3),
             'witness_search_ms': result.stats.get('witness_search_ms'),
             'certificate': verdict.verdict.value if verdict is not None else 'not assessed',
             'certificate_message': verdict.message if verdict is not None else '',
             'goal_valid_fraction': result.goal_valid_fraction, 'exported': None,
             'boxes_m': [[float(v) for v in o.shapes[0].pose.position_m]
                         for o in result.obstacles], 'victims': {},
             'witness_candidates': result.stats.get('witness_candidates', 1),
             **{key: result.stats[key] for key in EXIT_STATS if key in result.stats}}
    if 'direct_motion' in result.stats:  # the joint form: 'blocked' by the scene, or free
        entry['direct_motion'] = result.stats['direct_motion'] if 'direct_motion_cut' not in \
            result.stats else 'cut' if result.stats['direct_motion_cut'] else 'open'
    if not result.status.ok or verdict is None or not verdict.certified:
        return entry, None
    attacked = scene.with_objects(result.obstacles)
    # As `advocc export`: the witness is certified with the boxes before anything is written.
    why = certify(robot, CollisionWorld(robot, attacked.shapes), attacked.goal, result.witness,
                  q_init=q_init)[0]
    if why is not None:
        entry.update(certificate='not certified on export', certificate_message=why)
        return entry, None
    entry['witness_waypoints'] = int(len(result.witness.waypoints))
    clearance = result.stats.get('witness_scene_clearance_m')  # capped at the victim margin
    entry['witness_scene_clearance_m'] = (clearance[result.stats.get('witness_kept', 0)]
                                          if clearance else None)  # a lone candidate: 0
    return entry, attacked


def _export(folder: str, index: int, attacked, robot, witness, time_s: float) -> dict:
    """The attacked problem as MotionBenchMaker files (relative path -> YAML data)."""
    from advocc_ros.formats.mbm_export import (check_exportable, planning_scene_data,
                                               request_data, trajectory_data)

    check_exportable(attacked)
    return {f'{folder}/scene{index:04d}.yaml': planning_scene_data(attacked, robot),
            f'{folder}/request{index:04d}.yaml': request_data(attacked, robot, time_s),
            f'{folder}/trajectory{index:04d}.yaml': trajectory_data(
                robot.joint_names, witness.configurations(robot), robot.model.velocityLimit)}


def _cell(scene, victim: str, config: BuildConfig) -> dict:
    """One victim's row on one scene, as ``advocc evaluate --json`` computes it (every field
    of ``evaluation.metrics.aggregate``'s row), without the per-trial records; an exception
    becomes ``error`` (the other cells still run)."""
    from advocc_ros.evaluation.runner import evaluate_planner
    from advocc_ros.planning.victims import VictimConfig

    t = time.perf_counter()
    try:
        row = evaluate_planner(scene, victim, config.trials, config.time_s, config.seed,
                               workers=1, victim_config=VictimConfig())
    except Exception as exc:
        log.exception('victim %s failed', victim)
        return {'error': f'{type(exc).__name__}: {exc}'}
    drop = ('records', 'scene', 'planner', 'seed')  # per trial, or said by the file already
    return dict({k: v for k, v in row.items() if k not in drop},
                wall_s=round(time.perf_counter() - t, 3))


def _evaluate(scene, config: BuildConfig, attacks: dict, scenes: dict) -> dict:
    """Every victim on the unattacked scene and on each certified attacked one; fills the
    attack entries' ``victims`` (with the PT ratio) and returns the unattacked cells."""
    from advocc_ros.evaluation.hardness import pt_ratio

    unattacked = {}
    for victim in config.victims:
        base = unattacked[victim] = _cell(scene, victim, config)
        for budget, attacked in scenes.items():
            cell = _cell(attacked, victim, config)
            if 'error' not in cell and 'error' not in base:
                cell['pt_ratio'] = pt_ratio(cell, base)
            attacks[str(budget)]['victims'][victim] = cell
    return unattacked


def _hardness(problem: dict, config: BuildConfig, attacks: dict, unattacked: dict) -> dict:
    """``hardness.json``: per victim and budget PSR, failure modes, time to first solution,
    PT ratio and the certificate's verdict, and whether every victim is beaten."""
    for entry in attacks.values():
        cells = [entry['victims'].get(v) for v in config.victims]
        entry['all_victims_psr_le_20'] = (
            None if entry['exported'] is None or any(c is None or c.get('psr') is None
                                                     for c in cells)
            else all(c['psr'] <= PSR_HARD for c in cells))
    return {'format': HARDNESS_FORMAT, 'version': 1, 'family': problem['family'],
            'problem': f'{problem["index"]:04d}', 'split': problem['split'],
            'source': {'scene': f'{problem["family"]}/{problem["scene_name"]}',
                       'request': f'{problem["family"]}/{problem["request_name"]}'},
            'settings': config.to_json(), 'unattacked': unattacked, 'attacks': attacks}


__all__ = ['ALONE_CPUS', 'BuildConfig', 'FINAL_OUTCOMES', 'HARDNESS_FORMAT', 'MAX_LOG_BYTES',
           'OUTCOMES', 'PSR_HARD', 'posed', 'problem_input', 'provenance', 'run_problem',
           'task_log']
