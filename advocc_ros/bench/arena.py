"""Bench results in OMPL's benchmark format: its log files and the Planner Arena database.

OMPL and MoveIt users read benchmarks in Planner Arena (PyPI ``plannerarena``), which loads the
SQLite database that OMPL's ``ompl_benchmark_statistics.py`` makes from benchmark logs. A bench
run folder gets both, from its trial records:

- ``ompl_logs/<experiment>.log``: one OMPL benchmark log per experiment, i.e. per (scene,
  attack method, budget M), with one planner block per victim and one run line per trial;
  ``ompl_benchmark_statistics.py ompl_logs/*.log`` turns them into the same database;
- ``benchmark.db``: the tables that script makes (``experiments``, ``plannerConfigs``,
  ``enums``, ``runs``, ``progress``), written here directly with the same columns.

Runs carry OMPL's ``time`` (planning time [s]), ``solved``, ``status`` (here an enum of our
outcomes: success, the failure modes, internal error, so Planner Arena's status plot shows how
trials failed) and ``solution length`` (joint space [rad]), and ours: time to first solution,
whether the goal list searched before the clock found a goal and its IK attempts, SMR, CMR, JDS,
waypoints, seed. The scene, method and budget are experiment properties (Planner Arena's problem
parameters).
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import re
import socket
import sqlite3
import tempfile
import time

from advocc_ros import __version__
from advocc_ros.evaluation.outcomes import FAILURE_MODES, INTERNAL_ERROR, SUCCESS, record_outcome
from advocc_ros.fileio import atomic_write_text
from advocc_ros.evaluation.provenance import cpu_model

STATUS = (SUCCESS, *FAILURE_MODES, INTERNAL_ERROR)
"""The ``status`` enum of the runs: index -> outcome."""
RUN_PROPERTIES = (
    ('time', 'REAL', lambda r: r.get('planning_time_s')),
    ('solved', 'BOOLEAN', lambda r: int(bool(r.get('success')))),
    ('status', 'ENUM', lambda r: STATUS.index(record_outcome(r))),
    ('solution length', 'REAL', lambda r: r.get('path_length_rad')),
    ('first solution time', 'REAL', lambda r: r.get('first_solution_s')),
    ('goal found', 'BOOLEAN', lambda r: None if r.get('goal_found') is None
     else int(bool(r['goal_found']))),
    ('goal attempts', 'INTEGER', lambda r: r.get('goal_attempts')),
    ('smr', 'REAL', lambda r: r.get('min_manipulability')),
    ('cmr', 'REAL', lambda r: r.get('min_clearance_rad')),
    ('jds', 'REAL', lambda r: r.get('jds_rad')),
    ('waypoints', 'INTEGER', lambda r: r.get('waypoints')),
    ('seed', 'INTEGER', lambda r: r.get('seed')),
)
"""Per-run properties as OMPL logs them (name, SQL type, value of a trial record); the database
column is the name with ``_`` for spaces, as OMPL's script makes it."""


@dataclasses.dataclass
class Experiment:
    """One (scene, method, budget) of a bench run: its victims' trial records."""

    scene: str
    method: str
    budget: int
    time_limit_s: float
    runs: dict[str, list[dict]]
    """Planner name (``geometric_RRTConnect``, ``MPlib``, ...) -> trial records in trial
    order."""

    @property
    def name(self) -> str:
        """A name without spaces (OMPL's log keeps the last word of the line)."""
        scene = pathlib.Path(self.scene).stem if self.scene.endswith(('.yaml', '.yml')) \
            else self.scene
        return re.sub(r'[^A-Za-z0-9_.+-]', '_', f'{scene}_{self.method}_M{self.budget}')


def planner_name(victim: str) -> str:
    """Planner Arena's name of a victim: OMPL's ``geometric_<Class>`` for OMPL planners (OMPL
    2's marked ``_ompl2``), the label of an outside victim."""
    from advocc_ros.planning.types import planner_class_name
    from advocc_ros.planning.victims import OUTSIDE_LABELS
    from advocc_ros.planning.victims.ompl2 import PLANNERS as OMPL2

    key = victim.strip().lower()
    if key in OMPL2:
        return f'geometric_{OMPL2[key]}' + ('' if key == 'aorrtc' else '_ompl2')
    if key in OUTSIDE_LABELS:
        return OUTSIDE_LABELS[key]
    return f'geometric_{planner_class_name(victim) or victim}'


def experiments(records: list[dict], time_limit_s: float) -> list[Experiment]:
    """The records grouped into experiments (first appearance order), runs in trial order."""
    out: dict[tuple, Experiment] = {}
    for rec in records:
        key = (rec['scene'], rec['method'], int(rec['budget']))
        exp = out.setdefault(key, Experiment(*key, time_limit_s, {}))
        exp.runs.setdefault(planner_name(rec['planner']), []).append(rec)
    for exp in out.values():
        for runs in exp.runs.values():
            runs.sort(key=lambda r: r.get('trial', 0))
    return list(out.values())


def _value(value) -> str:
    return '' if value is None else repr(value)  # floats round-trip exactly


def log_text(exp: Experiment, setup: str, seed: int, host: str, cpu: str) -> str:
    """OMPL's benchmark log of one experiment (``ompl::tools::Benchmark``'s layout)."""
    started = min((r.get('unix') or time.time()) for runs in exp.runs.values() for r in runs)
    total = sum(r.get('planning_time_s') or 0.0 for runs in exp.runs.values() for r in runs)
    lines = [f'advocc_ros version {__version__}', f'Experiment {exp.name}',
             '3 experiment properties', f'scene VARCHAR(512) = {exp.scene}',
             f'method VARCHAR(128) = {exp.method}', f'budget INTEGER = {exp.budget}',
             f'Running on {host}',
             f'Starting at {time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started))}',
             '<<<|', setup, '|>>>', '<<<|', cpu, '|>>>', f'{seed} is the random seed',
             f'{exp.time_limit_s:g} seconds per run', '0 MB per run',
             f'{max(len(r) for r in exp.runs.values())} runs per planner',
             f'{total:.6g} seconds spent to collect the data', '1 enum type',
             '|'.join(('status', *STATUS)), f'{len(exp.runs)} planners']
    for planner, runs in exp.runs.items():
        lines += [planner, '1 common properties', f'victim = {runs[0]["planner"]}',
                  f'{len(RUN_PROPERTIES)} properties for each run']
        lines += [f'{name} {kind}' for name, kind, _ in RUN_PROPERTIES]
        lines.append(f'{len(runs)} runs')
        lines += [''.join(f'{_value(get(r))}; ' for _, _, get in RUN_PROPERTIES) for r in runs]
        lines.append('.')
    return '\n'.join(lines) + '\n'


_SCHEMA = '''
CREATE TABLE experiments (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512),
  totaltime REAL, timelimit REAL, memorylimit REAL, runcount INTEGER, version VARCHAR(128),
  hostname VARCHAR(1024), cpuinfo TEXT, date DATETIME, seed VARCHAR(24), setup TEXT,
  budget INTEGER, method VARCHAR(128), scene VARCHAR(512));
CREATE TABLE plannerConfigs (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512) NOT NULL,
  settings TEXT);
CREATE TABLE enums (name VARCHAR(512), value INTEGER, description TEXT,
  PRIMARY KEY (name, value));
CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, experimentid INTEGER, plannerid INTEGER,
  {columns},
  FOREIGN KEY (experimentid) REFERENCES experiments(id) ON DELETE CASCADE,
  FOREIGN KEY (plannerid) REFERENCES plannerConfigs(id) ON DELETE CASCADE);
CREATE TABLE progress (runid INTEGER, time REAL, PRIMARY KEY (runid, time),
  FOREIGN KEY (runid) REFERENCES runs(id) ON DELETE CASCADE);
'''
"""The tables of ``ompl_benchmark_statistics.py``: the fixed columns of ``experiments`` first
(Planner Arena reads the columns after the 12th as problem parameters), our experiment
properties after them in the order OMPL's script adds them (sorted)."""


def write_database(path: pathlib.Path, exps: list[Experiment], setup: str, seed: int,
                   host: str, cpu: str) -> None:
    """``path`` as the Planner Arena database of ``exps`` (atomic: a temp file renamed)."""
    columns = ',\n  '.join(f'{name.replace(" ", "_")} {kind}'
                           for name, kind, _ in RUN_PROPERTIES)
    fd, tmp = tempfile.mkstemp(suffix='.db', dir=path.parent)
    os.close(fd)
    try:
        conn = sqlite3.connect(tmp)
        with conn:
            conn.executescript(_SCHEMA.format(columns=columns))
            conn.executemany('INSERT INTO enums VALUES (?,?,?)',
                             [('status', i, s) for i, s in enumerate(STATUS)])
            planners: dict[tuple[str, str], int] = {}
            names = [name.replace(' ', '_') for name, _, _ in RUN_PROPERTIES]
            insert = (f'INSERT INTO runs (experimentid, plannerid, {", ".join(names)}) VALUES '
                      f'({", ".join("?" * (len(names) + 2))})')
            for exp in exps:
                started = min((r.get('unix') or time.time())
                              for runs in exp.runs.values() for r in runs)
                total = sum(r.get('planning_time_s') or 0.0
                            for runs in exp.runs.values() for r in runs)
                cur = conn.execute(
                    'INSERT INTO experiments (name, totaltime, timelimit, memorylimit, runcount, '
                    'version, hostname, cpuinfo, date, seed, setup, budget, method, scene) '
                    'VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)',
                    (exp.name, total, exp.time_limit_s, 0.0,
                     max(len(r) for r in exp.runs.values()), f'advocc_ros {__version__}', host,
                     cpu + '\n', time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(started)),
                     str(seed), setup + '\n', exp.budget, exp.method, exp.scene))
                exp_id = cur.lastrowid
                for planner, runs in exp.runs.items():
                    settings = f'victim = {runs[0]["planner"]};'
                    if (planner, settings) not in planners:
                        planners[(planner, settings)] = conn.execute(
                            'INSERT INTO plannerConfigs (name, settings) VALUES (?,?)',
                            (planner, settings)).lastrowid
                    conn.executemany(insert, [
                        (exp_id, planners[(planner, settings)],
                         *(get(r) for _, _, get in RUN_PROPERTIES)) for r in runs])
        conn.close()
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_ompl_results(run_dir: str | pathlib.Path, records: list[dict], cfg
                       ) -> dict[str, pathlib.Path]:
    """``run_dir/ompl_logs/*.log`` and ``run_dir/benchmark.db`` from a bench run's
    ``records`` under ``cfg`` (``BenchConfig``); name -> path of what was written."""
    run_dir = pathlib.Path(run_dir)
    exps = experiments(records, float(cfg.time_budget_s))
    if not exps:
        return {}
    setup = json.dumps(cfg.to_data(), sort_keys=True)
    host, cpu = socket.gethostname(), cpu_model()
    out = {}
    for exp in exps:
        name = f'ompl_logs/{exp.name}.log'
        atomic_write_text(run_dir / name, log_text(exp, setup, cfg.seed, host, cpu))
        out[name] = run_dir / name
    write_database(run_dir / 'benchmark.db', exps, setup, cfg.seed, host, cpu)
    out['benchmark.db'] = run_dir / 'benchmark.db'
    return out
