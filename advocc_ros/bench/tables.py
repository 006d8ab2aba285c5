"""The paper's Tables I, II and IV (Markdown and CSV) from trial records and attack metadata."""

from __future__ import annotations

import csv
import datetime
import io
import pathlib
from typing import Iterable

from advocc_ros.attack.methods import KNOWN_METHODS
from advocc_ros.bench.protocol import (BASELINE, METHOD_LABELS, PLANNER_LABELS,
                                       BenchConfig, scene_label)
from advocc_ros.evaluation.budgets import THRESHOLDS, minimal_budgets
from advocc_ros.evaluation.hardness import PSR_TIMES_S, pt_ratio, time_key
from advocc_ros.evaluation.metrics import aggregate
from advocc_ros.evaluation.outcomes import FAILURE_MODES


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
        row['expected'] = cfg.trials_for(cell[3], cell[0])
        row['complete'] = row['trials'] >= row['expected']
        rows[cell] = row
    return rows


def _fmt(value: float | None, digits: int) -> str:
    return 'N/A' if value is None else f'{value:.{digits}f}'


def _psr_cell(row: dict | None) -> str:
    if row is None:
        return '--'
    text = 'N/A' if row['psr'] is None else f'{100 * row["psr"]:.2f}'
    text += ('' if row['complete'] else '*') + ('!' if row['internal_errors'] else '')
    if row.get('no_goal_found'):  # PSR given goals beside it: the path search alone
        given = row['psr_given_goals']
        text += f' ({"N/A" if given is None else f"{100 * given:.2f}"} given goals, ' \
            f'{row["no_goal_found"]} without)'
    return text


# Table I metric: (row key, digits, better is lower)
_T1 = (('psr', 2, True), ('smr', 3, True), ('cmr', 3, True), ('jds', 3, False),
       ('pt', 3, False))


def table1(rows: dict[tuple, dict], cfg: BenchConfig) -> tuple[str, str]:
    """Table I (Markdown, CSV): PSR [%], SMR and CMR x10^-2, JDS [rad], PT [s] per budget.

    Bold marks the strongest attack per column like the paper (lowest PSR/SMR/CMR, highest
    JDS/PT); ``N/A``: undefined because PSR = 0; ``--``: not run; ``*``: fewer trials than
    planned; ``!``: some trials were internal errors, left out of PSR.
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
    md = ['| Scene | Planner | Trials | Internal errors | PSR | SMR | CMR | JDS | PT |',
          '|' + '---|' * 9]
    for scene in cfg.scenes:
        for planner in cfg.planners:
            row = rows.get((scene, planner, BASELINE, 0))
            if row is None:
                continue
            md.append('| ' + ' | '.join([
                scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
                str(row['trials']), str(row['internal_errors']), _psr_cell(row),
                _fmt(row['smr'], 3), _fmt(row['cmr'], 3),
                _fmt(row['jds'], 3), _fmt(row['pt'], 3)]) + ' |')
    return '\n'.join(md) + '\n'


def _rows_csv(rows: dict[tuple, dict], cfg: BenchConfig) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene_index', 'scene', 'planner', 'method', 'budget', 'trials',
                     'expected', 'successes', 'internal_errors', 'psr_percent', 'smr_x1e-2',
                     'cmr_x1e-2', 'jds_rad', 'pt_s', 'time_budget_s'])
    order = {s: i for i, s in enumerate(cfg.scenes)}
    for cell in sorted(rows, key=lambda c: (order.get(c[0], 99), c[1], c[2], c[3])):
        row = rows[cell]
        writer.writerow([order.get(cell[0], -1) + 1, *cell, row['trials'], row['expected'],
                         row['successes'], row['internal_errors'],
                         _csv_num(None if row['psr'] is None else 100 * row['psr']),
                         *(_csv_num(row[k]) for k in ('smr', 'cmr', 'jds', 'pt')),
                         row['time_budget_s']])
    return out.getvalue()


def _csv_num(value: float | None) -> str:
    return 'N/A' if value is None else f'{value:.6g}'


def _minimal(psr: dict[int, float], threshold: float) -> int | None:
    """Smallest measured budget whose PSR (a fraction) is <= ``threshold`` (a fraction;
    ``minimal_budgets``, the audit's prefix rule, over the measured budgets); None if none
    reaches it."""
    curve = [psr.get(m) for m in range(max(psr) + 1)] if psr else []
    return minimal_budgets({'p': curve}, (threshold,))[str(threshold)]['p']


def _percent(threshold: float) -> str:
    return f'{threshold * 100:.0f}'


def table2(rows: dict[tuple, dict], cfg: BenchConfig,
           families: dict[str, list[str]] | None = None) -> tuple[str, str]:
    """Table II (Markdown, CSV): minimum budget reaching PSR <= 80/60/40/20/0 %.

    Per scene, the smallest measured budget (0 = the unattacked scene, when run) at or below
    the threshold; with ``families`` (scene -> its variation scenes, ``variations``), the mean
    over the scene and its variations that reach it (fractional, like the paper's), ``(k/n)``
    when only k of n do, ``> max`` when none does within the largest measured budget.
    Greedy picks are nested, so budgets 1..K of one seed are the prefixes of one attack.
    """
    md = ['| Scene | Planner | Method | Budgets | Tasks | '
          + ' | '.join(f'{_percent(t)}%' for t in THRESHOLDS) + ' |',
          '|' + '---|' * (5 + len(THRESHOLDS))]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene', 'planner', 'method', 'budgets', 'tasks', 'max_budget',
                     *[f'psr_le_{_percent(t)}' for t in THRESHOLDS]])
    for scene in cfg.scenes:
        members = [scene, *(families or {}).get(scene, [])]
        for planner in cfg.planners:
            for method in cfg.methods:
                labels = [scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
                          METHOD_LABELS.get(method, method)]
                curves = []
                for member in members:
                    psr = {b: rows[(member, planner, method, b)]['psr'] for b in cfg.all_budgets
                           if (member, planner, method, b) in rows}
                    base = rows.get((member, planner, BASELINE, 0))
                    if psr and base is not None and base['psr'] is not None:
                        psr[0] = base['psr']
                    if psr:
                        curves.append(psr)
                if not curves:
                    md.append('| ' + ' | '.join(labels + ['--'] * (2 + len(THRESHOLDS)))
                              + ' |')
                    continue
                top = max(max(c) for c in curves)
                cells, values = [], []
                for t in THRESHOLDS:
                    reached = [m for m in (_minimal(c, t) for c in curves) if m is not None]
                    mean = sum(reached) / len(reached) if reached else None
                    values.append(mean)
                    text = f'> {top}' if mean is None else f'{mean:.2f}'.rstrip('0').rstrip('.')
                    if reached and len(reached) < len(curves):
                        text += f' ({len(reached)}/{len(curves)})'
                    cells.append(text)
                swept = ','.join(str(b) for b in sorted(set().union(*curves)))
                md.append('| ' + ' | '.join(labels + [swept, str(len(curves))] + cells) + ' |')
                writer.writerow([scene, planner, method, swept, len(curves), top,
                                 *[_csv_num(v) if v is not None else f'>{top}'
                                   for v in values]])
    return '\n'.join(md) + '\n', out.getvalue()


def _measured_cells(rows: dict[tuple, dict], cfg: BenchConfig):
    """(cell, row) of every measured cell in table order: scene, planner, the baseline first,
    then the methods by budget."""
    for scene in cfg.scenes:
        for planner in cfg.planners:
            for method in [BASELINE, *cfg.methods]:
                for budget in ([0] if method == BASELINE else cfg.all_budgets):
                    row = rows.get((scene, planner, method, budget))
                    if row is not None:
                        yield (scene, planner, method, budget), row


def _attack_values(attacks: list[dict], field: str) -> dict[tuple, list]:
    """``field`` of every attack file's metadata that has it, by (scene stem, method, budget);
    the stem is the attack folder's name (``attacks/<scene stem>/...``)."""
    values: dict[tuple, list] = {}
    for meta in attacks:
        value = meta.get(field)
        if value is not None and 'path' in meta:
            key = (pathlib.Path(meta['path']).parent.name, meta.get('method'),
                   int(meta.get('budget') or 0))
            values.setdefault(key, []).append(value)
    return values


def failure_table(rows: dict[tuple, dict], attacks: list[dict], cfg: BenchConfig,
                  stems: dict[str, str]) -> tuple[str, str]:
    """How the trials failed (Markdown, CSV): per cell, PSR, the failure-mode counts, the
    internal errors (not failures: left out of PSR) and the attacks' mean
    ``goal_valid_fraction`` (goal samples still valid with the boxes).

    ``attacks``: attack-file metadata with its ``path`` (``attacks/<scene stem>/...``);
    ``stems``: scene -> its file stem.
    """
    gvf = _attack_values(attacks, 'goal_valid_fraction')
    head = ['Scene', 'Planner', 'Method', 'M', 'Trials', 'PSR', *FAILURE_MODES,
            'internal errors', 'Goal valid']
    md = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene', 'planner', 'method', 'budget', 'trials', 'psr_percent',
                     *[m.replace(' ', '_') for m in FAILURE_MODES], 'internal_errors',
                     'goal_valid_fraction'])
    for (scene, planner, method, budget), row in _measured_cells(rows, cfg):
        fails = row.get('failures', {})
        values = [float(v) for v in gvf.get((stems.get(scene, scene), method, budget), [])]
        mean = sum(values) / len(values) if values else None
        md.append('| ' + ' | '.join([
            scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
            METHOD_LABELS.get(method, method), str(budget), str(row['trials']),
            _psr_cell(row), *[str(fails.get(m, 0)) for m in FAILURE_MODES],
            str(row.get('internal_errors', 0)),
            '1.00' if method == BASELINE else _fmt(mean, 2)]) + ' |')
        writer.writerow([scene, planner, method, budget, row['trials'],
                         _csv_num(None if row['psr'] is None else 100 * row['psr']),
                         *[fails.get(m, 0) for m in FAILURE_MODES],
                         row.get('internal_errors', 0),
                         _csv_num(1.0 if method == BASELINE else mean)])
    return '\n'.join(md) + '\n', out.getvalue()


def table4(attacks: list[dict], heatmaps: dict[str, dict]) -> tuple[str, str]:
    """Table IV (Markdown, CSV): offline and online time per method [s].

    ``attacks``: metadata of the attack files (``method``, ``planner``, ``compute_ms``; older
    files: ``compute_s``);
    ``heatmaps``: per scene, the heatmap's ``build_s`` (the offline cost of Ours).
    Online = mean core compute time of one attack; offline = mean heatmap build time.
    """
    groups: dict[tuple, list] = {}
    for meta in attacks:
        if meta.get('compute_ms') is not None:
            seconds = float(meta['compute_ms']) / 1e3
        elif meta.get('compute_s') is not None:
            seconds = float(meta['compute_s'])
        else:
            continue
        planner = meta.get('planner') if meta.get('planner_specific') else None
        groups.setdefault((meta['method'], planner), []).append(seconds)
    builds = [float(h['build_s']) for h in heatmaps.values() if h.get('build_s') is not None]
    offline_ours = sum(builds) / len(builds) if builds else None
    md = ['| Method | Offline time (s) | Online time (s) | Total time (s) | Attacks |',
          '|---|---|---|---|---|']
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['method', 'planner', 'offline_s', 'online_s', 'total_s', 'attacks'])
    order = [m for m in KNOWN_METHODS if m != 'ours'] + ['ours']  # baselines, then the paper's
    for method, planner in sorted(groups, key=lambda g: (
            order.index(g[0]) if g[0] in order else 99, g[0], g[1] or '')):
        times = groups[(method, planner)]
        online = sum(times) / len(times)
        offline = offline_ours if method in ('ours', 'task') else None  # both search H > 0
        total = online + (offline or 0.0)
        label = METHOD_LABELS.get(method, method)
        if planner:
            label += f' ({PLANNER_LABELS.get(planner, planner)})'
        md.append(f'| {label} | {_fmt(offline, 2) if offline is not None else "--"} | '
                  f'{online:.3f} | {total:.2f} | {len(times)} |')
        writer.writerow([method, planner or '', _csv_num(offline), f'{online:.6g}',
                         f'{total:.6g}', len(times)])
    return '\n'.join(md) + '\n', out.getvalue()


def hardness_table(rows: dict[tuple, dict], attacks: list[dict], cfg: BenchConfig,
                   stems: dict[str, str]) -> tuple[str, str]:
    """Hardness beyond PSR (Markdown, CSV): per cell, PSR at 1/2/5 s (30 s when the budget
    allows) read off the time to first solution, its median and p90 (failures at the budget),
    the PT ratio against the unattacked cell, and the attacks' ``solvable`` verdicts
    (c certified / b goal blocked / u unknown; ``--`` when the attacks did not say).

    PSR@t is ``--`` when the trials did not report their first-solution time; the median and
    the PT ratio then use the planning time (an upper bound), marked ``+``.
    """
    times = [t for t in PSR_TIMES_S if t <= cfg.time_budget_s + 1e-9]
    verdicts = _attack_values(attacks, 'solvable')
    head = ['Scene', 'Planner', 'Method', 'M', 'Trials', 'PSR', *[f'PSR@{t:g}s' for t in times],
            'T1st median [s]', 'T1st p90 [s]', 'PT ratio', 'Solvable c/b/u']
    md = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['scene', 'planner', 'method', 'budget', 'trials', 'psr_percent',
                     *[f'psr_at_{t:g}s_percent' for t in times], 'first_solution_median_s',
                     'first_solution_p90_s', 'first_solution_measured', 'pt_ratio',
                     'certified', 'goal_blocked', 'unknown'])
    for (scene, planner, method, budget), row in _measured_cells(rows, cfg):
        psr_at = [row['psr_at'].get(time_key(t)) for t in times]
        mark = '' if row['first_solution_measured'] else '+'
        ratio = pt_ratio(row, rows.get((scene, planner, BASELINE, 0)))
        counts = _verdict_counts(verdicts.get((stems.get(scene, scene), method, budget), []))
        md.append('| ' + ' | '.join([
            scene_label(cfg, scene), PLANNER_LABELS.get(planner, planner),
            METHOD_LABELS.get(method, method), str(budget), str(row['trials']), _psr_cell(row),
            *['--' if v is None else f'{100 * v:.0f}' for v in psr_at],
            _fmt(row['first_solution_median_s'], 3) + mark,
            _fmt(row['first_solution_p90_s'], 3) + mark,
            '--' if ratio is None else f'x{ratio:.2f}{mark}',
            '--' if counts is None else '/'.join(map(str, counts))]) + ' |')
        writer.writerow([scene, planner, method, budget, row['trials'],
                         _csv_num(None if row['psr'] is None else 100 * row['psr']),
                         *[_csv_num(None if v is None else 100 * v) for v in psr_at],
                         _csv_num(row['first_solution_median_s']),
                         _csv_num(row['first_solution_p90_s']),
                         int(row['first_solution_measured']), _csv_num(ratio),
                         *(counts or ('', '', ''))])
    return '\n'.join(md) + '\n', out.getvalue()


def _verdict_counts(values: list) -> tuple[int, int, int] | None:
    """(certified, goal blocked, unknown) among attack ``solvable`` entries (a verdict or a
    mapping with one); None without entries."""
    if not values:
        return None
    found = [v.get('verdict') if isinstance(v, dict) else v for v in values]
    certified, blocked = found.count('certified'), found.count('goal blocked')
    return certified, blocked, len(found) - certified - blocked


CELL_COLUMNS = ('run', 'seed', 'scene', 'planner', 'method', 'budget', 'trials', 'psr_percent',
                'psr_given_goals_percent', 'no_goal_found',
                *[m.replace(' ', '_') for m in FAILURE_MODES], 'internal_errors',
                'goal_valid_fraction', 'first_solution_median_s', 'pt_ratio', 'certified',
                'goal_blocked', 'unknown', 'first_trial_utc', 'last_trial_utc', 'commit',
                'dirty', 'host', 'cpu', 'load_1min_max')
"""The columns of ``cells.csv``."""


def cell_table(rows: dict[tuple, dict], attacks: list[dict], records: Iterable[dict],
               cfg: BenchConfig, stems: dict[str, str], run: str) -> str:
    """``cells.csv``: one row per cell of the records (budgets a resumed run no longer lists
    included), everything a study's results file holds (docs/results), so that file is this
    one copied, never put together by hand: the run (its folder's name) and seed, the cell, its
    trials, PSR and PSR given goals (the trials whose goal search before the clock found one)
    with the trials where it found none, the failure modes, the internal errors, the attacks'
    mean ``goal_valid_fraction`` and their ``solvable`` verdicts, the median time to first
    solution (failures at the budget), the PT ratio, when the cell's first and last trials
    were recorded (UTC) and what recorded them (``provenance.stamp``: the commits, whether any
    was dirty, the hosts, the CPUs, the highest load; empty for records made before it)."""
    gvf = _attack_values(attacks, 'goal_valid_fraction')
    verdicts = _attack_values(attacks, 'solvable')
    made: dict[tuple, list[dict]] = {}
    for rec in records:
        made.setdefault((rec['scene'], rec['planner'], rec['method'], int(rec['budget'])),
                        []).append(rec)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(CELL_COLUMNS)
    for cell in sorted(rows, key=lambda c: _cell_order(c, cfg)):
        row = rows[cell]
        scene, planner, method, budget = cell
        stem = stems.get(scene, scene)
        values = [float(v) for v in gvf.get((stem, method, budget), [])]
        counts = _verdict_counts(verdicts.get((stem, method, budget), []))
        fails = row.get('failures', {})
        writer.writerow([
            run, cfg.seed, *cell, row['trials'], _csv_percent(row['psr']),
            _csv_percent(row.get('psr_given_goals')), row.get('no_goal_found', 0),
            *[fails.get(m, 0) for m in FAILURE_MODES], row.get('internal_errors', 0),
            _csv_num(1.0 if method == BASELINE else
                     sum(values) / len(values) if values else None),
            _csv_num(row['first_solution_median_s']),
            _csv_num(pt_ratio(row, rows.get((scene, planner, BASELINE, 0)))),
            *(counts or ('', '', '')),
            *_made_cells(made.get(cell, []))])
    return out.getvalue()


def _made_cells(records: list[dict]) -> list:
    """The ``first_trial_utc``, ``last_trial_utc``, ``commit``, ``dirty``, ``host``, ``cpu`` and
    ``load_1min_max`` cells of a cell's records: the first and last record times, each distinct
    value once (space-separated; the CPU's ``; ``), dirty when any was, the highest load; empty
    where no record names it."""
    unix = [float(r['unix']) for r in records if r.get('unix') is not None]

    def distinct(key: str, sep: str = ' ') -> str:
        return sep.join(sorted({str(r[key]) for r in records if r.get(key) is not None}))
    dirty = [bool(r['dirty']) for r in records if r.get('dirty') is not None]
    loads = [float(r['load_1min']) for r in records if r.get('load_1min') is not None]
    return [*[_utc(f(unix)) if unix else '' for f in (min, max)],
            distinct('commit'), int(any(dirty)) if dirty else '', distinct('host'),
            distinct('cpu', '; '), _csv_num(max(loads)) if loads else '']


def _cell_order(cell: tuple, cfg: BenchConfig) -> tuple:
    """Table order of a cell, those of settings a resumed run no longer lists included:
    scene, planner, the baseline first, then the methods by budget."""
    scene, planner, method, budget = cell
    methods = [BASELINE, *cfg.methods]

    def index(items, item) -> tuple:
        items = list(items)
        return (items.index(item), '') if item in items else (len(items), str(item))
    return index(cfg.scenes, scene), index(cfg.planners, planner), index(methods, method), budget


def _csv_percent(share: float | None) -> str:
    return _csv_num(None if share is None else 100 * share)


def _utc(unix: float) -> str:
    return datetime.datetime.fromtimestamp(unix, datetime.timezone.utc).strftime(
        '%Y-%m-%d %H:%M UTC')
