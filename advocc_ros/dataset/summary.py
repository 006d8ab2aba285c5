"""The data set's summary: per family and split, how problems ended and how hard the built ones
are; written as ``summary.json``, ``summary.md`` and ``summary.png``, beside ``problems.csv``
(one row per problem, budget and victim: the table the summary pools).

Read from the records of the selected problems (a build's selection; for ``advocc dataset
summary``, the selection of the folder's last run), not from whatever else the folder holds, so a
resumed build and a fresh one on the same selection summarise alike. Per group (a family and a
split; ``all`` pools the families):

- the share of each outcome (``job.OUTCOMES``);
- per budget M, over the problems whose budget-M attack was certified and evaluated: the share
  where *every* victim is at PSR <= 20 %, each victim's mean PSR, and the median PT ratio
  (attacked / unattacked median time to first solution, ``evaluation.hardness.pt_ratio``) over
  victims and problems; per victim the share of problems where it is at PSR <= 20 % and its
  PSR given goals with the share of problems where that is <= 50 %; and per
  victim checker asked about the witnesses (``mplib``), how many it accepts;
- the victims' mean PSR on the unattacked problems, and the share of those already at PSR
  <= 20 % for every victim (MotionBenchMaker kept only problems its planner solves in 60 s;
  at a budget of a few seconds some are hard before any box): the line the attack starts from.
"""

from __future__ import annotations

import pathlib
import statistics

from advocc_ros.dataset import machines, store
from advocc_ros.dataset.job import ALONE_CPUS, FINAL_OUTCOMES, OUTCOMES, PSR_HARD
from advocc_ros.evaluation.provenance import SPEED_SPREAD

SUMMARY_FORMAT = 'advocc_dataset_summary'
FIGURE = 'summary.png'
TABLE = 'problems.csv'
GIVEN_GOALS_HARD = 0.5
"""The PSR at or below which a victim handed valid goals (no goal sampling: path search alone)
counts as held."""
PROVENANCE_COLUMNS = ('commit', 'dirty', 'host', 'cpu', 'cpus', 'threads', 'victims_cpus_alone',
                      'speed_checks_per_s', 'load_start', 'load_end', 'started', 'finished',
                      'versions')
"""The columns of ``problems.csv`` that name a row's making (the problem's ``provenance``:
``speed_checks_per_s`` the machine's speed before the work (``provenance.speed``), ``load_*``
the 1-minute load average, ``versions`` ``name=version`` pairs)."""
TABLE_COLUMNS = ('family', 'problem', 'split', 'goal_form', 'outcome', 'budget', 'certificate',
                 'boxes', 'witness_waypoints', 'direct_motion', 'witness_accepted_by_mplib',
                 'goal_escape_p', 'victim', 'trials', 'psr', 'psr_given_goals', 'no_goal_found',
                 'first_solution_median_s', 'pt_ratio', 'unattacked_psr') + PROVENANCE_COLUMNS
"""``problems.csv``: budget 0 rows are the unattacked problem; a problem without a hardness
record (refused, no witness, timeout, ...) has one row with its outcome only;
``goal_escape_p``: the attacked joint goal's escape share (``BuildConfig.escape_rays``);
``direct_motion`` (joint form): the straight motion from the start to the goal ``blocked`` by
the scene, or free on it and ``cut`` by the boxes or left ``open``."""


def _mean(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(statistics.fmean(values)) if values else None


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(statistics.median(values)) if values else None


def _group(family: str, split: str, items: list[tuple[dict, dict | None]], budgets: list[str],
           victims: list[str]) -> dict:
    n = len(items)
    outcomes = {k: sum(r['outcome'] == k for r, _ in items) for k in OUTCOMES}
    hard = [h for r, h in items if r['outcome'] == 'built' and h]
    per_budget = {}
    for b in budgets:
        attacks = [h['attacks'][b] for h in hard if h.get('attacks', {}).get(b, {}).get(
            'all_victims_psr_le_20') is not None]
        cells = {v: [a['victims'].get(v, {}) for a in attacks] for v in victims}
        per_budget[b] = {
            'evaluated': len(attacks),
            'all_victims_psr_le_20': (sum(a['all_victims_psr_le_20'] for a in attacks)
                                      / len(attacks) if attacks else None),
            'median_pt_ratio': _median([c.get('pt_ratio') for v in victims for c in cells[v]]),
            'witness_checks': _witness_checks(attacks),
            'victims': {v: _victim_cells(cells[v]) for v in victims}}
    base = [[h['unattacked'].get(v, {}).get('psr') for v in victims] for h in hard]
    base = [all(p <= PSR_HARD for p in row) for row in base if None not in row]
    return {'family': family, 'split': split, 'problems': n, 'outcomes': outcomes,
            'shares': {k: v / n if n else None for k, v in outcomes.items()},
            'unattacked': {v: _unattacked([h['unattacked'].get(v, {}) for h in hard])
                           for v in victims},
            'unattacked_evaluated': len(base),
            'unattacked_all_victims_psr_le_20': sum(base) / len(base) if base else None,
            'budgets': per_budget}


def _share(values: list, bar: float) -> float | None:
    values = [v for v in values if v is not None]
    return sum(v <= bar for v in values) / len(values) if values else None


def _victim_cells(cells: list[dict]) -> dict:
    """One victim at one budget over the evaluated attacks: its mean PSR, the share of problems
    where it is at PSR <= 20 %, the median PT ratio, and its mean PSR given goals (over the
    trials that had a goal: a victim handed a goal list, MPlib, without those where the list's
    search found none; the PSR for the others) with the share of problems where that is <= 50 %."""
    psr, given = [c.get('psr') for c in cells], [c.get('psr_given_goals') for c in cells]
    return {'mean_psr': _mean(psr), 'psr_le_20': _share(psr, PSR_HARD),
            'median_pt_ratio': _median([c.get('pt_ratio') for c in cells]),
            'mean_psr_given_goals': _mean(given),
            'psr_given_goals_le_50': _share(given, GIVEN_GOALS_HARD)}


def _unattacked(cells: list[dict]) -> dict:
    return {'mean_psr': _mean([c.get('psr') for c in cells]),
            'mean_psr_given_goals': _mean([c.get('psr_given_goals') for c in cells])}


def _witness_checks(attacks: list[dict]) -> dict:
    """Per victim checker (``job.mplib_witness_check``): of the evaluated attacks' witnesses,
    how many it was asked about and how many it accepts."""
    out: dict = {}
    for attack in attacks:
        for checker, check in (attack.get('witness_checks') or {}).items():
            counts = out.setdefault(checker, {'checked': 0, 'accepted': 0})
            counts['checked'] += 1
            counts['accepted'] += bool(check.get('accepted'))
    return out


def selected(out: pathlib.Path) -> list[str] | None:
    """The problems (``family/NNNN``) the last run of ``out`` selected; None when its build
    record names none (then every record counts)."""
    build = store.read_build(out)
    runs = build['runs'] if build else []
    problems = runs[-1].get('selection', {}).get('problems') if runs else None
    return list(problems) if isinstance(problems, list) else None


def _settings(out: pathlib.Path) -> dict:
    """The build settings (``BuildConfig.to_json``) of the build folder ``out``."""
    return (store.read_build(out) or {}).get('settings', {}).get('build', {})


def summarise(out: pathlib.Path, keys: list[str] | None = None) -> dict:
    """The summary of the problems ``keys`` (default: ``selected``) recorded under ``out``
    (see the module docstring)."""
    keys = selected(out) if keys is None else keys
    found = store.records(out, keys)
    settings = _settings(out)
    budgets = [str(b) for b in settings.get('budgets', [])]
    victims = list(settings.get('victims', []))
    groups = []
    for split in ('train', 'test'):
        items = [(r, h) for r, h in found if r.get('split') == split]
        if not items:
            continue
        for family in sorted({r['family'] for r, _ in items}):
            groups.append(_group(family, split, [(r, h) for r, h in items
                                                 if r['family'] == family], budgets, victims))
        groups.append(_group('all', split, items, budgets, victims))
    return {'format': SUMMARY_FORMAT, 'version': 2, 'problems': len(found),
            'selected': len(keys) if keys is not None else len(found),
            'settings': settings, 'budgets': budgets, 'victims': victims, 'groups': groups,
            'made': _made([r for r, _ in found]),
            'errors': [f'{r["family"]}/{r["problem"]}: {r["outcome"]}: {r.get("reason")}'
                       for r, _ in found if r['outcome'] not in FINAL_OUTCOMES]}


def _made(found: list[dict]) -> dict:
    """What made the records: their commits (a ``+dirty`` suffix for a changed checkout), how
    many problems evaluated their victims with the CPUs alone, shared or unknown (an older
    record without provenance), and the speeds of the machines that built them."""
    commits: dict[str, int] = {}
    timing = {'victims_cpus_alone': 0, 'shared': 0, 'unknown': 0}
    for record in found:
        made = record.get('provenance') or {}
        name = (made.get('commit') or 'unknown') + ('+dirty' if made.get('dirty') else '')
        commits[name] = commits.get(name, 0) + 1
        if record['outcome'] == 'built':
            alone = made.get('victims_cpus_alone')
            timing['unknown' if alone is None else 'victims_cpus_alone' if alone
                   else 'shared'] += 1
    return {'commits': commits, 'timing_of_built_problems': timing,
            'speed_of_built_problems': machines.speeds(machines.built_speeds(found))}


def table_rows(out: pathlib.Path, keys: list[str] | None = None) -> list[dict]:
    """The rows of ``problems.csv`` for the problems ``keys`` (default: ``selected``)."""
    rows = []
    form = _settings(out).get('goal_form', 'region')
    for record, hardness in store.records(out, selected(out) if keys is None else keys):
        key = dict({'family': record['family'], 'problem': record['problem'],
                    'split': record.get('split'), 'goal_form': form,
                    'outcome': record['outcome']},
                   **_provenance_cells(record.get('provenance') or {}))
        if not hardness:
            rows.append(key)
            continue
        base = hardness.get('unattacked', {})
        for victim, cell in base.items():
            rows.append(dict(key, budget=0, victim=victim, **_cell(cell)))
        for budget, attack in hardness.get('attacks', {}).items():
            accepted = attack.get('witness_checks', {}).get('mplib', {}).get('accepted')
            escape = attack.get('goal_escape')
            head = dict(key, budget=int(budget), certificate=attack.get('certificate'),
                        boxes=attack.get('boxes'),
                        witness_waypoints=attack.get('witness_waypoints'),
                        direct_motion=attack.get('direct_motion'),
                        witness_accepted_by_mplib=accepted,
                        goal_escape_p=escape['free'] / escape['rays'] if escape else None)
            for victim, cell in attack.get('victims', {}).items():
                rows.append(dict(head, victim=victim, **_cell(cell),
                                 unattacked_psr=base.get(victim, {}).get('psr')))
            if not attack.get('victims'):
                rows.append(head)
    return rows


def _provenance_cells(made: dict) -> dict:
    """The ``PROVENANCE_COLUMNS`` of a record's provenance (empty cells when it has none)."""
    def first(values):
        return values[0] if isinstance(values, list) and values else None
    versions = made.get('versions') or {}
    return {'commit': made.get('commit'), 'dirty': made.get('dirty'), 'host': made.get('host'),
            'cpu': made.get('cpu'), 'cpus': made.get('cpus'), 'threads': made.get('threads'),
            'victims_cpus_alone': made.get('victims_cpus_alone'),
            'speed_checks_per_s': made.get('speed_checks_per_s'),
            'load_start': first(made.get('load')), 'load_end': first(made.get('load_end')),
            'started': made.get('started'), 'finished': made.get('finished'),
            'versions': ' '.join(f'{k}={v}' for k, v in versions.items() if v) or None}


def _cell(cell: dict) -> dict:
    return {k: cell.get(k) for k in ('trials', 'psr', 'psr_given_goals', 'no_goal_found',
                                     'first_solution_median_s', 'pt_ratio')}


def csv_text(rows: list[dict], columns=TABLE_COLUMNS) -> str:
    """``rows`` as CSV with a header of ``columns`` (``problems.csv``'s by default)."""
    import csv
    import io

    text = io.StringIO()
    writer = csv.DictWriter(text, columns, lineterminator='\n')
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue()


def _pct(value) -> str:
    return '–' if value is None else f'{100 * value:.0f} %'


def _num(value) -> str:
    return '–' if value is None else f'{value:.2f}'


def markdown(summary: dict) -> str:
    """``summary.md``: what made it, one table per split, then the problems not finished."""
    budgets, victims = summary['budgets'], summary['victims']
    s = summary['settings']
    outcomes = [k for k in OUTCOMES if k in FINAL_OUTCOMES
                or any(g['outcomes'][k] for g in summary['groups'])]
    lines = ['# Certified hard problems: summary', '',
             f'{summary["problems"]} of {summary["selected"]} selected problems recorded; goal '
             f'form `{s.get("goal_form", "region")}`; `task` attack under `solvable` at M = '
             f'{", ".join(budgets)}; victims {", ".join(victims)}; {s.get("trials")} trials x '
             f'{s.get("time_s")} s each. "All <= 20 %": share of the problems with a certified '
             'attack at M where every victim is at PSR <= 20 %. PT ratio: median over victims '
             'and problems of attacked / unattacked median time to first solution. "Unattacked: '
             'all <= 20 %": the same share before any box (the baseline). Problems '
             '0001-0040 of each family are the train split, 0041-0100 the test split.', '',
             _made_text(summary['made']), '']
    checkers = sorted({c for g in summary['groups'] for b in budgets
                       for c in g['budgets'][b].get('witness_checks', {})})
    head = ['family', 'problems'] + outcomes + ['unattacked: all <= 20 %']
    for b in budgets:
        head += [f'M={b}: all <= 20 %', f'M={b}: PT ratio']
        head += [f'M={b}: witness accepted by {c}' for c in checkers]
    for split in ('train', 'test'):
        rows = [g for g in summary['groups'] if g['split'] == split]
        if not rows:
            continue
        lines += [f'## {split} split', '', '| ' + ' | '.join(head) + ' |',
                  '|' + '---|' * len(head)]
        for g in rows:
            cells = [f'**{g["family"]}**' if g['family'] == 'all' else g['family'],
                     str(g['problems'])]
            cells += [f'{g["outcomes"][k]} ({_pct(g["shares"][k])})' for k in outcomes]
            cells.append(f'{_pct(g["unattacked_all_victims_psr_le_20"])} of '
                         f'{g["unattacked_evaluated"]}')
            for b in budgets:
                cell = g['budgets'][b]
                cells += [f'{_pct(cell["all_victims_psr_le_20"])} of {cell["evaluated"]}',
                          _num(cell['median_pt_ratio'])]
                checks = cell.get('witness_checks', {})
                cells += [f'{checks[c]["accepted"]} of {checks[c]["checked"]}' if c in checks
                          else '–' for c in checkers]
            lines.append('| ' + ' | '.join(cells) + ' |')
        lines.append('')
    if summary['errors']:
        lines += ['## Not finished (redone by the next build over this folder; a timeout only '
                  'with a larger --problem-timeout)', '']
        lines += [f'- {e}' for e in summary['errors']] + ['']
    lines += [f'![mean PSR per budget and share of problems beaten per family]({FIGURE})', '']
    return '\n'.join(lines)


def _made_text(made: dict) -> str:
    """The paragraph of ``summary.md`` that says what made the records."""
    timing = made['timing_of_built_problems']
    commits = ', '.join(f'`{c[:12]}{"+dirty" if c.endswith("+dirty") else ""}` ({n})'
                        for c, n in made['commits'].items()) or 'none'
    speed = made.get('speed_of_built_problems') or machines.speeds([])
    text = (f'Made by commit(s) {commits}. Victims timed with their CPUs alone (each problem '
            f'held >= {ALONE_CPUS} CPUs) on {timing["victims_cpus_alone"]} built problem(s), '
            f'with CPUs shared on {timing["shared"]}, unknown on {timing["unknown"]}: time '
            'figures (PT ratio, time to first solution) are faithful only for the first.')
    if speed['known']:
        text += (f' Machine speed (validity checks/s before the work) {speed["min"]:,.0f} to '
                 f'{speed["max"]:,.0f} on {speed["known"]} built problem(s) of '
                 f'{len(speed["machines"])} machine(s), unknown on {speed["unknown"]}')
        text += '.' if speed['pooled'] else (
            f': the machines\' medians {speed["spread"]:.2f}x apart, more than {SPEED_SPREAD:g}x: '
            'a budget of seconds bought that much more planning on the fastest, so their '
            'PSRs do not pool.')
    return text


def figure(summary: dict, path: pathlib.Path) -> None:
    """``summary.png``: each victim's mean PSR against the budget (0 = unattacked) per split,
    and per family the share of problems where every victim is at PSR <= 20 %."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from advocc_ros.fileio import atomic_open

    budgets, victims = summary['budgets'], summary['victims']
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5),
                                      gridspec_kw={'width_ratios': [1, 1.4]})
    styles = {'train': '-', 'test': '--'}
    xs = [0] + [int(b) for b in budgets]
    for split, style in styles.items():
        pooled = next((g for g in summary['groups']
                       if g['family'] == 'all' and g['split'] == split), None)
        if pooled is None:
            continue
        for k, v in enumerate(victims):
            ys = [pooled['unattacked'][v]['mean_psr']] + [
                pooled['budgets'][b]['victims'][v]['mean_psr'] for b in budgets]
            left.plot(xs, [float('nan') if y is None else 100 * y for y in ys], style,
                      marker='o', color=f'C{k}', label=f'{v} ({split})')
    left.axhline(20, color='grey', lw=0.8, ls=':')
    left.set(xlabel='boxes M (0: unattacked)', ylabel='mean PSR [%]', ylim=(-3, 103),
             xticks=xs, title='Victims on certified attacks')
    left.legend(fontsize=7)
    groups = [g for g in summary['groups'] if g['family'] != 'all']
    labels = [f'{g["family"].removesuffix("_panda")}\n{g["split"]}' for g in groups]
    columns = [('unattacked', 'unattacked_all_victims_psr_le_20', 'unattacked_evaluated')] + [
        (b, 'all_victims_psr_le_20', 'evaluated') for b in budgets]
    width = 0.8 / len(columns)
    for k, (b, share_key, count_key) in enumerate(columns):
        cells = [g if b == 'unattacked' else g['budgets'][b] for g in groups]
        cells = [{'share': c[share_key], 'evaluated': c[count_key]} for c in cells]
        shares = [c['share'] for c in cells]
        bars = right.bar([i + (k - (len(columns) - 1) / 2) * width for i in range(len(groups))],
                         [0 if s is None else 100 * s for s in shares], width,
                         label='unattacked' if b == 'unattacked' else f'M = {b}',
                         color='0.7' if b == 'unattacked' else f'C{k - 1}')
        right.bar_label(bars, [f'{round((s or 0) * c["evaluated"])}/{c["evaluated"]}'
                               for s, c in zip(shares, cells)], fontsize=6)
    right.set_xticks(range(len(groups)), labels, fontsize=7)
    right.set(ylabel='problems with every victim at PSR <= 20 % [%]', ylim=(0, 103),
              title='Beaten problems per family')
    right.legend(fontsize=8)
    fig.tight_layout()
    with atomic_open(path, 'wb') as handle:
        fig.savefig(handle, format='png', dpi=110)
    plt.close(fig)


def write_summary(out: pathlib.Path, keys: list[str] | None = None) -> dict:
    """Write ``summary.json``, ``summary.md``, ``summary.png`` and ``problems.csv`` of the
    problems ``keys`` (default: ``selected``) into ``out``; the summary."""
    from advocc_ros.fileio import atomic_write_text

    keys = selected(out) if keys is None else keys
    summary = summarise(out, keys)
    store.write_json(out / 'summary.json', summary)
    atomic_write_text(out / 'summary.md', markdown(summary))
    atomic_write_text(out / TABLE, csv_text(table_rows(out, keys)))
    figure(summary, out / FIGURE)
    return summary


__all__ = ['FIGURE', 'PROVENANCE_COLUMNS', 'SUMMARY_FORMAT', 'TABLE', 'TABLE_COLUMNS',
           'csv_text', 'markdown', 'selected', 'summarise', 'table_rows',
           'write_summary']
