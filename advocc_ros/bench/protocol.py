"""Benchmark bookkeeping (paper §V, SPEC §4/§7): protocol, run plan, records, tables. No ROS.

The orchestrator (``advocc_ros.orchestrator.run``) drives real nodes; everything it needs to decide
*what* to run and to turn results into the paper's tables lives here, so it can be tested on
hand-made records:

- ``BenchConfig``: one protocol (a profile of ``config/bench.yaml`` plus command-line overrides).
- ``plan_units``: the run plan. A *unit* is one planning scene to inject (an attack, or none for
  the unattacked baseline) and the trials to run in it. Attacks that do not depend on the victim
  (ours, random, pfa) serve every planner from one injection; planner-specific ones (pfa++) get
  one unit per planner. A method with ``variants: R`` splits a cell's trials into R contiguous
  blocks, each against its own attack (seed + v), so a Random cell is not one lucky draw.
- ``RecordStore``: per-trial JSON lines, appended with flush + fsync, deduplicated by trial key
  on load, tolerant of a truncated last line (a kill mid-write), so a re-run resumes exactly.
- ``cell_rows`` / ``table1`` / ``table2`` / ``table4``: the paper's Tables I, II and IV as
  Markdown and CSV.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import fcntl
import io
import json
import logging
import math
import os
import pathlib
import re
from typing import Any, Iterable

import yaml

from advocc_ros.limits import MAX_TRIALS
from advocc_ros.evaluation.metrics import aggregate

log = logging.getLogger(__name__)

BASELINE = 'none'
"""Method name of the unattacked baseline (budget 0)."""
THRESHOLDS = (80, 60, 40, 20, 0)
"""Table II: PSR thresholds [%]."""
METHOD_LABELS = {'ours': 'Ours', 'random': 'Random', 'pfa': 'PFA', 'pfa++': 'PFA++',
                 BASELINE: 'None'}
PLANNER_LABELS = {'rrtconnect': 'RRT', 'prmstar': 'PRM*', 'bkpiece1': 'BKPIECE'}
MAX_BUDGET = 90
"""Largest budget: one attack's REMOVE + ADDs must fit the latched topic's history (100)."""
# Settings that change what a trial measures: a run folder refuses to mix them.
IDENTITY_FIELDS = ('time_budget_s', 'seed', 'box_size_m', 'heatmap_samples',
                   'heatmap_robot_only', 'variants')


class BenchError(ValueError):
    """A protocol, profile or run folder that cannot be used; the message says why."""


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """One benchmark protocol; defaults are the paper's (§V-A)."""

    scenes: tuple[str, ...] = ('table_pick', 'table_under_pick', 'bookshelf')
    """Scene names (config/scenes) or scene YAML paths; 'Scene i' in tables is 1-based order."""
    planners: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1')
    methods: tuple[str, ...] = ('ours', 'random', 'pfa', 'pfa++')
    budgets: tuple[int, ...] = (1, 3, 5)
    """Budgets M of Table I (trials each)."""
    trials: int = 500
    """Trials per (scene, planner, method, budget) cell and for the baseline."""
    time_budget_s: float = 5.0
    """Planning budget of one trial [s]; a failure counts this as PT."""
    sweep_budgets: tuple[int, ...] = ()
    """Extra budgets for Table II's budget-to-failure sweep (with ``budgets`` and 0)."""
    sweep_trials: int | None = None
    """Trials of a sweep-only budget (None: ``trials``)."""
    baseline: bool = True
    """Also run the unattacked scene (budget 0) per scene x planner."""
    variants: dict = dataclasses.field(default_factory=dict)
    """Attacks per cell by method (e.g. random: 10); trials are split between them."""
    planner_specific: tuple[str, ...] = ('pfa++',)
    """Methods whose attack queries the victim planner: one attack per planner."""
    skip: tuple[str, ...] = ('pfa++:rrtconnect',)
    """``method:planner`` pairs not run ("--" in the tables; PFA++ on RRT is PFA)."""
    seed: int = 0
    """Trial k plans with seed ``seed + k``; attack variant v uses seed ``seed + v``."""
    shims: int = 2
    """Local planner_shim processes per scene."""
    external_shims: bool = False
    """Also use planner shims of the same ROS domain found by their ``*/plan`` services."""
    heatmap_samples: int = 15_000
    heatmap_robot_only: bool = False
    heatmap_workers: int = 2
    box_size_m: float = 0.0
    """Box edge [m]; 0: the heatmap server's default (0.05 m)."""
    attack_timeout_s: float = 120.0
    """Longest wait for one attack (planner-in-the-loop methods need long ones)."""
    start_timeout_s: float = 120.0
    """Longest wait for a started node's services [s]."""
    plan_timeout_margin_s: float = 30.0
    """A plan request unanswered ``time_budget_s`` + this long marks its shim as hung [s]."""
    max_restarts: int = 5
    """Restarts of one node per scene before the benchmark gives up."""
    pfa: dict = dataclasses.field(default_factory=dict)
    """Settings of the planner-in-the-loop methods (``advocc_ros.attack.pfa.PfaConfig`` fields:
    queries, queries_per_placement, query_time_s, ...); their queries run on the shims."""

    def __post_init__(self):
        def fail(what: str) -> None:
            raise BenchError(f'bench setting {what}')

        for name in ('scenes', 'planners', 'methods'):
            value = getattr(self, name)
            if not value or not all(isinstance(v, str) and v for v in value):
                fail(f'{name}: expected a non-empty list of names, got {value!r}')
            if len(set(value)) != len(value):
                fail(f'{name}: duplicates in {list(value)}')
        for name in ('budgets', 'sweep_budgets'):
            for b in getattr(self, name):
                if isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= MAX_BUDGET:
                    fail(f'{name}: budgets must be integers in 1..{MAX_BUDGET}, got {b!r}')
        if not self.budgets and not self.sweep_budgets and not self.baseline:
            fail('budgets: nothing to run')
        for name in ('trials', 'shims', 'heatmap_samples', 'heatmap_workers'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (
                    0 if name == 'shims' else 1):
                fail(f'{name}={value!r} is out of range')
        if self.trials > MAX_TRIALS:
            fail(f'trials={self.trials} exceeds the limit {MAX_TRIALS} (limits.MAX_TRIALS)')
        if self.sweep_trials is not None and (not isinstance(self.sweep_trials, int)
                                              or not 1 <= self.sweep_trials <= MAX_TRIALS):
            fail(f'sweep_trials={self.sweep_trials!r} must be an integer in 1..{MAX_TRIALS}')
        if self.shims == 0 and not self.external_shims:
            fail('shims=0 needs external_shims: nobody would plan')
        for name in ('time_budget_s', 'attack_timeout_s', 'start_timeout_s',
                     'plan_timeout_margin_s'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                fail(f'{name}={value!r} must be a finite number > 0')
        if not (isinstance(self.box_size_m, (int, float)) and 0 <= self.box_size_m <= 0.5):
            fail(f'box_size_m={self.box_size_m!r} must be in [0, 0.5] (0: server default)')
        if not isinstance(self.pfa, dict) or 'planner_id' in self.pfa:
            fail(f'pfa: expected a mapping of PfaConfig settings (the planner is the cell\'s), '
                 f'got {self.pfa!r}')
        if not isinstance(self.variants, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1
                for v in self.variants.values()):
            fail(f'variants: expected method: count >= 1, got {self.variants!r}')
        for pair in self.skip:
            if not isinstance(pair, str) or pair.count(':') != 1:
                fail(f'skip: expected "method:planner" entries, got {pair!r}')

    @property
    def all_budgets(self) -> tuple[int, ...]:
        return tuple(sorted(set(self.budgets) | set(self.sweep_budgets)))

    def trials_for(self, budget: int) -> int:
        if budget == 0 or budget in self.budgets or self.sweep_trials is None:
            return self.trials
        return self.sweep_trials

    def skipped(self, method: str, planner: str) -> bool:
        return f'{method}:{planner}' in self.skip

    def to_data(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_data(cls, data: dict, where: str = 'bench config') -> 'BenchConfig':
        if not isinstance(data, dict):
            raise BenchError(f'{where}: expected a mapping, got {type(data).__name__}')
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise BenchError(f'{where}: unknown settings {unknown}; known: {sorted(names)}')
        values = {}
        for key, value in data.items():
            if key in ('scenes', 'planners', 'methods', 'budgets', 'sweep_budgets',
                       'planner_specific', 'skip'):
                if not isinstance(value, (list, tuple)):
                    raise BenchError(f'{where}.{key}: expected a list, got {value!r}')
                value = tuple(value)
            values[key] = value
        try:
            return cls(**values)
        except TypeError as exc:
            raise BenchError(f'{where}: {exc}') from None


def load_profile(path: str | pathlib.Path, name: str) -> BenchConfig:
    """Profile ``name`` of a bench YAML file (``profiles: {name: {setting: value}}``)."""
    path = pathlib.Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BenchError(f'{path}: cannot read ({exc})') from None
    profiles = data.get('profiles') if isinstance(data, dict) else None
    if not isinstance(profiles, dict) or not profiles:
        raise BenchError(f'{path}: expected a mapping with profiles: {{name: settings}}')
    if name not in profiles:
        raise BenchError(f'{path}: no profile {name!r}; profiles: {sorted(profiles)}')
    return BenchConfig.from_data(profiles[name] or {}, f'{path}:{name}')


# --------------------------------------------------------------------------------------------
# Run plan

@dataclasses.dataclass(frozen=True)
class AttackSpec:
    """One attack to generate (and cache in the run folder)."""

    scene: str
    method: str
    budget: int
    variant: int = 0
    planner: str | None = None
    """Victim planner of a planner-specific attack (pfa++), else None."""
    seed: int = 0

    @property
    def tag(self) -> str:
        """File-name and object-id safe name, unique within a scene."""
        method = self.method.replace('+', 'p')
        planner = f'_{self.planner}' if self.planner else ''
        return re.sub(r'[^A-Za-z0-9_]', '_', f'{method}_b{self.budget}{planner}_v{self.variant}')


@dataclasses.dataclass(frozen=True)
class Trial:
    """One plan request of the protocol."""

    scene: str
    planner: str
    method: str
    budget: int
    trial: int
    seed: int

    @property
    def key(self) -> str:
        return trial_key(self.scene, self.planner, self.method, self.budget, self.trial)

    @property
    def cell(self) -> tuple[str, str, str, int]:
        return self.scene, self.planner, self.method, self.budget


def trial_key(scene: str, planner: str, method: str, budget: int, trial: int) -> str:
    return f'{scene}|{planner}|{method}|{int(budget)}|{int(trial)}'


@dataclasses.dataclass
class Unit:
    """A planning scene to inject (``attack`` None: the unattacked scene) and its trials."""

    scene: str
    attack: AttackSpec | None
    trials: list[Trial]


def scene_label(cfg: BenchConfig, scene: str) -> str:
    name = pathlib.Path(scene).stem if scene.endswith(('.yaml', '.yml')) else scene
    return f'Scene {cfg.scenes.index(scene) + 1} ({name})'


def plan_units(cfg: BenchConfig, available: Iterable[str] | None = None
               ) -> tuple[list[Unit], list[str]]:
    """The run plan in execution order (scene-major) and notes on what is skipped and why.

    ``available``: methods that can be generated (None: all); the others are skipped.
    """
    available = set(cfg.methods if available is None else available)
    notes = []
    for method in cfg.methods:
        if method not in available:
            notes.append(f'method {method!r} skipped: not available in this installation')
    for pair in cfg.skip:
        method, planner = pair.split(':')
        if method in cfg.methods and planner in cfg.planners:
            notes.append(f'{method} on {planner} not run (configured skip: {pair})')
    units: list[Unit] = []
    for scene in cfg.scenes:
        if cfg.baseline:
            trials = [Trial(scene, p, BASELINE, 0, k, cfg.seed + k)
                      for p in cfg.planners for k in range(cfg.trials_for(0))]
            units.append(Unit(scene, None, trials))
        for method in cfg.methods:
            if method not in available:
                continue
            planners = [p for p in cfg.planners if not cfg.skipped(method, p)]
            groups = [[p] for p in planners] if method in cfg.planner_specific else [planners]
            for budget in cfg.all_budgets:
                n = cfg.trials_for(budget)
                n_var = max(1, min(int(cfg.variants.get(method, 1)), n))
                for group in groups:
                    if not group:
                        continue
                    for v in range(n_var):
                        spec = AttackSpec(scene, method, budget, v,
                                          group[0] if method in cfg.planner_specific else None,
                                          cfg.seed + v)
                        ks = [k for k in range(n) if k * n_var // n == v]
                        units.append(Unit(scene, spec, [Trial(scene, p, method, budget, k,
                                                              cfg.seed + k)
                                                        for p in group for k in ks]))
    return units, notes


# --------------------------------------------------------------------------------------------
# Records

class RecordStore:
    """Per-trial records as JSON lines; one line per finished trial, never two per key."""

    def __init__(self, path: str | pathlib.Path):
        self.path = pathlib.Path(path)
        self.records: dict[str, dict] = {}
        self.duplicates = 0
        self.bad_lines = 0
        self._load()

    def _load(self) -> None:
        if not self.path.exists():
            return
        raw = self.path.read_bytes()
        lines = raw.split(b'\n')
        tail = lines.pop()  # b'' when the file ends with a newline
        for i, line in enumerate(lines):
            self._take(line, i + 1)
        if tail:
            # A kill mid-append leaves a partial last line: keep it only if it is whole JSON.
            if self._take(tail, len(lines) + 1, warn=False):
                with open(self.path, 'ab') as handle:
                    handle.write(b'\n')
            else:
                log.warning('%s: dropping a truncated last line (%d bytes)', self.path,
                            len(tail))
                with open(self.path, 'r+b') as handle:
                    handle.truncate(len(raw) - len(tail))
            with open(self.path, 'rb+') as handle:
                os.fsync(handle.fileno())

    def _take(self, line: bytes, number: int, warn: bool = True) -> bool:
        if not line.strip():
            return True
        try:
            rec = json.loads(line)
            key = rec['key']
        except (ValueError, KeyError, TypeError):
            if warn:
                log.warning('%s:%d: skipping an unreadable record', self.path, number)
                self.bad_lines += 1
            return False
        if key in self.records:
            self.duplicates += 1  # only a foreign writer could do this: keep the first
        else:
            self.records[key] = rec
        return True

    def __contains__(self, key: str) -> bool:
        return key in self.records

    def __len__(self) -> int:
        return len(self.records)

    def append(self, record: dict) -> bool:
        """Append one finished trial durably; False if its key is already recorded."""
        key = record['key']
        if key in self.records:
            return False
        line = (json.dumps(record, sort_keys=True, allow_nan=False) + '\n').encode()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line)
            os.fsync(fd)
        finally:
            os.close(fd)
        self.records[key] = record
        return True


@contextlib.contextmanager
def run_lock(run_dir: pathlib.Path):
    """Exclusive lock on a run folder: two orchestrators on one folder would duplicate trials.
    The kernel drops it when the holder dies, even by SIGKILL."""
    run_dir.mkdir(parents=True, exist_ok=True)
    handle = open(run_dir / '.lock', 'w')
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise BenchError(f'{run_dir} is in use by another benchmark process') from None
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        handle.close()


def check_run_config(run_dir: pathlib.Path, cfg: BenchConfig) -> None:
    """Refuse to resume a run folder whose trials were measured under other settings."""
    path = run_dir / 'config.json'
    if not path.exists():
        return
    try:
        old = json.loads(path.read_text())['config']
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchError(f'{path}: unreadable ({exc}); remove it to start over') from None
    new = cfg.to_data()
    diff = [f'{k}: {old.get(k)!r} -> {new[k]!r}' for k in IDENTITY_FIELDS if old.get(k) != new[k]]
    if diff:
        raise BenchError(f'{run_dir} holds trials measured with other settings ({"; ".join(diff)})'
                         '; use another --out folder')


# --------------------------------------------------------------------------------------------
# Aggregation and tables

def cell_rows(records: Iterable[dict], cfg: BenchConfig) -> dict[tuple, dict]:
    """Table row per (scene, planner, method, budget) with ``expected`` trial counts."""
    groups: dict[tuple, list] = {}
    for rec in records:
        cell = (rec['scene'], rec['planner'], rec['method'], int(rec['budget']))
        groups.setdefault(cell, []).append(rec)
    rows = {}
    for cell, recs in groups.items():
        row = aggregate(recs, float(recs[0].get('time_budget_s', cfg.time_budget_s)))
        row['expected'] = cfg.trials_for(cell[3])
        row['complete'] = row['trials'] >= row['expected']
        rows[cell] = row
    return rows


def _fmt(value: float | None, digits: int) -> str:
    return 'N/A' if value is None else f'{value:.{digits}f}'


def _psr_cell(row: dict | None) -> str:
    if row is None or row['psr'] is None:
        return '--'
    text = f'{100 * row["psr"]:.2f}'
    return text if row['complete'] else f'{text}*'


# Table I metric: (row key, digits, better is lower)
_T1 = (('psr', 2, True), ('smr', 3, True), ('cmr', 3, True), ('jds', 3, False),
       ('pt', 3, False))


def table1(rows: dict[tuple, dict], cfg: BenchConfig) -> tuple[str, str]:
    """Table I (Markdown, CSV): PSR [%], SMR and CMR x10^-2, JDS [rad], PT [s] per budget.

    Bold marks the strongest attack per column like the paper (lowest PSR/SMR/CMR, highest
    JDS/PT); ``N/A``: undefined because PSR = 0; ``--``: not run; ``*``: fewer trials than
    planned.
    """
    budgets = list(cfg.budgets)
    head = ['Scene', 'Planner', 'Method'] + [f'{m.upper()}@{b}' for b in budgets
                                             for m, _, _ in _T1]
    md = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    methods = [m for m in cfg.methods]
    for scene in cfg.scenes:
        for planner in cfg.planners:
            best: dict[tuple, float] = {}
            for b in budgets:
                for key, _, lower in _T1:
                    vals = [rows[(scene, planner, m, b)][key] for m in methods
                            if (scene, planner, m, b) in rows
                            and rows[(scene, planner, m, b)][key] is not None]
                    if len(vals) > 1:
                        best[(b, key)] = min(vals) if lower else max(vals)
            for method in methods:
                cells = [scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
                         METHOD_LABELS.get(method, method)]
                for b in budgets:
                    row = rows.get((scene, planner, method, b))
                    for key, digits, _ in _T1:
                        if row is None:
                            cells.append('--')
                            continue
                        text = _psr_cell(row) if key == 'psr' else _fmt(row[key], digits)
                        value = row[key]
                        if value is not None and (b, key) in best and \
                                round(value, digits + (2 if key == 'psr' else 0)) == \
                                round(best[(b, key)], digits + (2 if key == 'psr' else 0)):
                            text = f'**{text}**'
                        cells.append(text)
                md.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(md) + '\n', _rows_csv(rows, cfg)


def baseline_table(rows: dict[tuple, dict], cfg: BenchConfig) -> str:
    """The unattacked scenes (budget 0), Markdown."""
    md = ['| Scene | Planner | Trials | PSR | SMR | CMR | JDS | PT |', '|' + '---|' * 8]
    for scene in cfg.scenes:
        for planner in cfg.planners:
            row = rows.get((scene, planner, BASELINE, 0))
            if row is None:
                continue
            md.append('| ' + ' | '.join([
                scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
                str(row['trials']), _psr_cell(row), _fmt(row['smr'], 3), _fmt(row['cmr'], 3),
                _fmt(row['jds'], 3), _fmt(row['pt'], 3)]) + ' |')
    return '\n'.join(md) + '\n'


def _rows_csv(rows: dict[tuple, dict], cfg: BenchConfig) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene_index', 'scene', 'planner', 'method', 'budget', 'trials',
                     'expected', 'successes', 'psr_percent', 'smr_x1e-2', 'cmr_x1e-2', 'jds_rad',
                     'pt_s', 'time_budget_s'])
    order = {s: i for i, s in enumerate(cfg.scenes)}
    for cell in sorted(rows, key=lambda c: (order.get(c[0], 99), c[1], c[2], c[3])):
        row = rows[cell]
        writer.writerow([order.get(cell[0], -1) + 1, *cell, row['trials'], row['expected'],
                         row['successes'], _csv_num(None if row['psr'] is None
                                                    else 100 * row['psr']),
                         *(_csv_num(row[k]) for k in ('smr', 'cmr', 'jds', 'pt')),
                         row['time_budget_s']])
    return out.getvalue()


def _csv_num(value: float | None) -> str:
    return 'N/A' if value is None else f'{value:.6g}'


def budget_to_failure(psr_by_budget: dict[int, float], threshold_percent: float
                      ) -> int | None:
    """Smallest measured budget whose PSR is <= the threshold; None if none reaches it."""
    for budget in sorted(psr_by_budget):
        if 100 * psr_by_budget[budget] <= threshold_percent + 1e-9:
            return budget
    return None


def table2(rows: dict[tuple, dict], cfg: BenchConfig) -> tuple[str, str]:
    """Table II (Markdown, CSV): minimum measured budget reaching PSR <= 80/60/40/20/0 %.

    The sweep is the measured budgets (0 = the unattacked scene, when run); ``> max`` when the
    largest measured budget does not reach the threshold.
    """
    md = ['| Scene | Planner | Method | Budgets | ' + ' | '.join(f'{t}%' for t in THRESHOLDS)
          + ' |', '|' + '---|' * (4 + len(THRESHOLDS))]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene', 'planner', 'method', 'budgets', 'max_budget',
                     *[f'psr_le_{t}' for t in THRESHOLDS]])
    for scene in cfg.scenes:
        for planner in cfg.planners:
            base = rows.get((scene, planner, BASELINE, 0))
            for method in cfg.methods:
                psr = {b: rows[(scene, planner, method, b)]['psr'] for b in cfg.all_budgets
                       if (scene, planner, method, b) in rows}
                labels = [scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
                          METHOD_LABELS.get(method, method)]
                if not psr:
                    md.append('| ' + ' | '.join(labels + ['--'] * (1 + len(THRESHOLDS)))
                              + ' |')
                    continue
                if base is not None and base['psr'] is not None:
                    psr[0] = base['psr']
                top = max(psr)
                values = [budget_to_failure(psr, t) for t in THRESHOLDS]
                cells = [str(v) if v is not None else f'> {top}' for v in values]
                swept = ','.join(str(b) for b in sorted(psr))
                md.append('| ' + ' | '.join(labels + [swept] + cells) + ' |')
                writer.writerow([scene, planner, method, swept, top,
                                 *[v if v is not None else f'>{top}' for v in values]])
    return '\n'.join(md) + '\n', out.getvalue()


def table4(attacks: list[dict], heatmaps: dict[str, dict]) -> tuple[str, str]:
    """Table IV (Markdown, CSV): offline and online time per method [s].

    ``attacks``: metadata of the attack files (``method``, ``planner``, ``compute_s``);
    ``heatmaps``: per scene, the heatmap's ``build_s`` (the offline cost of Ours).
    Online = mean core compute time of one attack; offline = mean heatmap build time.
    """
    groups: dict[tuple, list] = {}
    for meta in attacks:
        if meta.get('compute_s') is None:
            continue
        planner = meta.get('planner') if meta.get('planner_specific') else None
        groups.setdefault((meta['method'], planner), []).append(float(meta['compute_s']))
    builds = [float(h['build_s']) for h in heatmaps.values() if h.get('build_s') is not None]
    offline_ours = sum(builds) / len(builds) if builds else None
    md = ['| Method | Offline time (s) | Online time (s) | Total time (s) | Attacks |',
          '|---|---|---|---|---|']
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['method', 'planner', 'offline_s', 'online_s', 'total_s', 'attacks'])
    order = ['random', 'pfa', 'pfa++', 'ours']
    for method, planner in sorted(groups, key=lambda g: (
            order.index(g[0]) if g[0] in order else 99, g[0], g[1] or '')):
        times = groups[(method, planner)]
        online = sum(times) / len(times)
        offline = offline_ours if method == 'ours' else None
        total = online + (offline or 0.0)
        label = METHOD_LABELS.get(method, method)
        if planner:
            label += f' ({PLANNER_LABELS.get(planner, planner)})'
        md.append(f'| {label} | {_fmt(offline, 2) if offline is not None else "--"} | '
                  f'{online:.3f} | {total:.2f} | {len(times)} |')
        writer.writerow([method, planner or '', _csv_num(offline), f'{online:.6g}',
                         f'{total:.6g}', len(times)])
    return '\n'.join(md) + '\n', out.getvalue()


def progress_summary(store: RecordStore, units: list[Unit]) -> dict[str, Any]:
    """Planned, finished and missing trials of a run plan."""
    planned = [t.key for u in units for t in u.trials]
    done = sum(1 for k in planned if k in store)
    return {'planned': len(planned), 'done': done, 'missing': len(planned) - done,
            'records': len(store), 'duplicates_on_load': store.duplicates,
            'bad_lines_on_load': store.bad_lines}
