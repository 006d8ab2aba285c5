"""An audit's report: the answer, the per-budget table, ``audit.md``, ``audit.json`` and the
figures (``advocc_ros.audit.audit`` computes the audit). No ROS."""

from __future__ import annotations

import pathlib

from advocc_ros.audit.audit import ANSWER_THRESHOLD
from advocc_ros.evaluation.hardness import pt_ratio


def planner_label(planner_id: str) -> str:
    """``RRTConnect``, ``PRM*``, ``BKPIECE1``: the OMPL class name, ``star`` as ``*``; an
    outside victim's label (``MPlib``)."""
    from advocc_ros.planning.types import planner_class_name
    from advocc_ros.planning.victims import OUTSIDE_LABELS

    if planner_id in OUTSIDE_LABELS:
        return OUTSIDE_LABELS[planner_id]
    name = planner_class_name(planner_id) or planner_id
    return name.replace('star', '*')


SKIPPED = '—'
"""A cell not evaluated: the planner was already at the target PSR (or the table's notes)."""


def _pct(value: float | None) -> str:
    return 'N/A' if value is None else f'{100 * value:.0f} %'


def _threshold(audit: dict) -> float:
    """The PSR at which a planner "fails" in the answer: the audit's target, else 20 %."""
    target = audit['settings'].get('target_psr')
    return ANSWER_THRESHOLD if target is None else target


def _entry(audit: dict, m: int) -> dict | None:
    """Prefix m's entry of ``budgets`` (None: not evaluated); version 2 and 3 alike."""
    return next((b for b in audit['budgets'] if b['m'] == m), None)


def _row(audit: dict, m: int, planner: str) -> dict | None:
    """``planner``'s row at prefix m, None when it was not evaluated there."""
    entry = _entry(audit, m)
    return None if entry is None else entry['planners'].get(planner)


def _last_m(audit: dict, planner: str | None = None) -> int:
    """The last evaluated prefix (of ``planner``, when given)."""
    return max(b['m'] for b in audit['budgets']
               if planner is None or b['planners'].get(planner) is not None)


def prefix_boxes(audit: dict, m: int) -> list[dict]:
    """The boxes of prefix m: the first m of the audit's attack, or those its entry holds (an
    early version 4 file, written while a prefix could be an attack of its own)."""
    entry = _entry(audit, m)
    return entry['boxes'] if entry is not None and 'boxes' in entry else audit['boxes'][:m]


def _gap(audit: dict, m: int, planner: str) -> str:
    """`` (m = a..b not evaluated)`` when prefixes just below m were not evaluated for
    ``planner`` (a coarse ``--prefixes`` grid): the fewest boxes lies in a..m."""
    below = [b['m'] for b in audit['budgets']
             if b['m'] < m and b['planners'].get(planner) is not None]
    first = max(below, default=-1) + 1
    if first >= m:
        return ''
    return f' (m = {first}{"" if first == m - 1 else f"..{m - 1}"} not evaluated)'


def _boxes(m: int | None) -> str:
    return f'{m} box' if m == 1 else f'{m} boxes'


def _failures(row: dict) -> str:
    counts = dict(row['failures'], **{'internal errors': row.get('internal_errors', 0)})
    text = ', '.join(f'{n} {mode}' for mode, n in counts.items() if n)
    return text or '-'


def audit_answer(audit: dict) -> str:
    """The headline: how few boxes make the pick impossible, and per planner how few make it
    fail (PSR <= the target, else 20 %; and 0 %) while the task stays certified solvable."""
    s = audit['settings']
    lines = [f'Audit of {audit["scene"]}: attack {audit["method_label"]} (goal policy '
             f'{audit["policy"]}, {s["box_size_m"]} m boxes, up to {audit["max_budget"]}), '
             f'{s["trials"]} trials x {s["time_budget_s"]:g} s per planner and budget.',
             impossible_answer(audit),
             'Fewest boxes that make each planner fail while the task stays certified '
             'solvable (a witness path stays valid):']
    lines += [f'- {_planner_answer(audit, planner)}.' for planner in audit['psr']]
    if s.get('prefixes') is not None:
        lines.append('Prefixes evaluated (--prefixes): m = '
                     + ', '.join(str(b['m']) for b in audit['budgets'])
                     + '; the m between them were not, so a fewest-boxes answer is an upper '
                     'bound.')
    last = _last_m(audit)
    placed = ', '.join(f'#{b["pick"]} at {b["center_m"]}' for b in prefix_boxes(audit, last))
    if placed:
        lines.append(f'Boxes of m = {last} (robot base frame, pick order): {placed}.')
    lines.append('Goal poses left valid: ' + ', '.join(
        f'm={b["m"]}: {_pct(b["goal_valid_fraction"])}' for b in audit['budgets'])
        + f'. Stopped: {audit["stopped"]}.')
    return '\n'.join(lines)


def impossible_answer(audit: dict) -> str:
    """How few boxes of the paper-policy attack leave no collision-free goal configuration."""
    imp = audit['impossible']
    which = 'this attack' if imp['same_attack'] else \
        f'the {audit["method_label"]} attack under goal policy paper'
    m = imp['goal_blocked_m']
    if m is None:
        verdicts = ', '.join(f'm={p["m"]} {p["solvable"]}' for p in imp['prefixes'])
        return (f'Impossible: no prefix of {which} blocks the goal (up to '
                f'{_boxes(len(imp["prefixes"]))}: {verdicts or "no boxes placed"}).')
    why = imp['prefixes'][m - 1]['solvability'].get('message', '')
    return (f'Impossible: {_boxes(m)} of {which} {"makes" if m == 1 else "make"} the pick '
            f'impossible for every planner (goal blocked{": " + why if why else ""}).')


def _planner_answer(audit: dict, planner: str) -> str:
    """One planner's line: its fewest boxes to fail while certified, else why not."""
    label, curve, limit = planner_label(planner), audit['psr'][planner], _threshold(audit)
    fail = audit['min_budget_solvable'][str(limit)][planner]
    zero = audit['min_budget_solvable'][str(0.0)][planner]
    if fail is not None:
        text = (f'{label} fails (PSR <= {_pct(limit)}) with {_boxes(fail)}'
                f'{_gap(audit, fail, planner)}, task certified: PSR {_pct(curve[0])} -> '
                f'{_pct(curve[fail])} ({_failures(_row(audit, fail, planner))})')
        if zero is not None and zero != fail:
            text += f'; PSR 0 % with {_boxes(zero)}'
        return text
    certified = [b['m'] for b in audit['budgets'] if b['solvable'] == 'certified'
                 and b['planners'].get(planner) is not None]
    if not certified:
        text = f'{label}: no prefix it was evaluated on is certified solvable'
    else:
        low = min(certified, key=lambda m: (curve[m] is None, curve[m] or 0.0, -m))
        text = (f'{label} does not fail (PSR > {_pct(limit)}) on a certified prefix (m = '
                f'{", ".join(map(str, certified))}): lowest PSR {_pct(curve[low])} at m = {low}'
                f' (unattacked {_pct(curve[0])}), median time to first solution '
                f'{_seconds(audit, 0, planner)} -> {_seconds(audit, low, planner)}')
        ratio = pt_ratio(_row(audit, low, planner), _row(audit, 0, planner))
        if ratio is not None:
            text += f' (PT ratio x{ratio:.2f})'
    anyway = audit['min_budget'][str(limit)][planner]
    if anyway is not None:
        text += (f'; it fails with {_boxes(anyway)}{_gap(audit, anyway, planner)}, where the '
                 f'task is {_entry(audit, anyway)["solvable"]}')
    return text


def _seconds(audit: dict, m: int, planner: str) -> str:
    """Median time to first solution of ``planner`` at prefix m (failures at the budget)."""
    row = _row(audit, m, planner)
    value = None if row is None else row['first_solution_median_s']
    return 'N/A' if value is None else f'{value:.2f} s'


def budget_table(audit: dict) -> str:
    """Markdown: per m, the verdict, goal-valid fraction, and per planner PSR, median time to
    first solution (failures at the budget) and failures."""
    planners = list(audit['psr'])
    head = ['m', 'solvable', 'goal valid'] + [f'{planner_label(p)} {c}' for p in planners
                                              for c in ('PSR', 'T1st', 'failures')]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for b in audit['budgets']:
        cells = [str(b['m']), b['solvable'], _pct(b['goal_valid_fraction'])]
        for p in planners:
            row = b['planners'].get(p)
            cells += [SKIPPED] * 3 if row is None else [
                _pct(row['psr']), _seconds(audit, b['m'], p), _failures(row)]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines + _table_notes(audit))


def _table_notes(audit: dict) -> list[str]:
    """Footnotes of the budget table: what its skipped rows and cells mean."""
    notes = []
    if any(row is None for b in audit['budgets'] for row in b['planners'].values()):
        notes.append(f'{SKIPPED}: not evaluated, the planner was already at PSR <= '
                     f'{_pct(_threshold(audit))} (--target-psr).')
    evaluated = [b['m'] for b in audit['budgets']]
    missing = sorted(set(range(max(evaluated) + 1)) - set(evaluated))
    if missing:
        notes.append(f'm = {", ".join(map(str, missing))}: not evaluated (not in --prefixes).')
    return [''] + notes if notes else []


def _min_budget_table(audit: dict, key: str) -> list[str]:
    """Markdown lines: per planner, the minimal budget per PSR threshold of ``audit[key]``."""
    thresholds = list(audit[key])
    out = ['| planner | ' + ' | '.join(f'PSR <= {float(t) * 100:g} %' for t in thresholds)
           + ' |', '|' + '---|' * (1 + len(thresholds))]
    for p in audit['psr']:
        cells = [audit[key][t][p] for t in thresholds]
        out.append(f'| {planner_label(p)} | '
                   + ' | '.join(f'> {_last_m(audit, p)}' if c is None else str(c)
                                for c in cells) + ' |')
    return out


def audit_markdown(audit: dict) -> str:
    """The whole ``audit.md``: answer, per-budget table, minimal budgets, boxes, settings."""
    s, planners = audit['settings'], list(audit['psr'])
    out = [f'# Audit: {audit["scene"]}', '', '## Answer', '', audit_answer(audit), '',
           '## PSR per budget', '', budget_table(audit), '',
           '## Minimal budget per PSR threshold, task certified solvable', '',
           *_min_budget_table(audit, 'min_budget_solvable'), '',
           '## Minimal budget per PSR threshold, any verdict', '',
           *_min_budget_table(audit, 'min_budget'), '',
           '"> m": not reached on the prefixes the planner was evaluated on (up to m).']
    evaluated = _last_m(audit)
    out += ['', '## Boxes in pick order', '',
            '| # | id | centre [m] | marginal mass | evaluated |', '|---|---|---|---|---|']
    for b in audit['boxes']:
        out.append(f'| {b["pick"]} | {b["id"]} | {b["center_m"]} | {b["mass"]:.4g} | '
                   f'{"yes" if b["pick"] <= evaluated else "no (stopped earlier)"} |')
    out += ['', 'Box #m is the last box of prefix m (edge '
            f'{s["box_size_m"]} m, robot base frame).', '',
            '![slices](audit_slices.png)', '', '![PSR vs budget](audit_psr.png)', '',
            '## Settings', '',
            f'- attack: {audit["method"]}, goal policy {audit["policy"]}, max budget '
            f'{audit["max_budget"]}, seed {s["seed"]}: {audit["attack"]["status"]} '
            f'({audit["attack"]["message"]}), {audit["attack"]["compute_ms"]:.1f} ms',
            *([f'- task options (--task-option): {s["task_options"]}']
              if s.get('task_options') else []),
            f'- goal-blocked answer: {_impossible_attack(audit)}',
            f'- witness: {_witness(audit["witness"])}',
            f'- planners: {", ".join(planners)}; {s["trials"]} trials, '
            f'{s["time_budget_s"]:g} s per plan, {s["workers"]} worker processes',
            f'- heatmap: {s["heatmap"]["valid_samples"]} samples, built for '
            f'{s["heatmap"]["scene_name"]}',
            f'- wall time: {audit["wall_s"]} s (attack, then the evaluations) on '
            f'{audit["machine"]["cpu"]} ({audit["machine"]["cores"]} cores), Python '
            f'{audit["machine"]["python"]}', '']
    return '\n'.join(out)


def _impossible_attack(audit: dict) -> str:
    imp = audit['impossible']
    if imp['same_attack']:
        return 'the prefixes of this attack'
    return (f'a second attack, goal policy paper: {imp["attack"]["status"]} '
            f'({imp["attack"]["message"]}), boxes '
            + ', '.join(f'#{b["pick"]} at {b["center_m"]}' for b in imp['boxes']))


def _witness(witness: dict | None) -> str:
    if witness is None:
        return 'none found on the unattacked scene (no prefix can be certified)'
    return 'found on the unattacked scene (' + ', '.join(
        f'{k} {v}' for k, v in witness['source'].items()) + '; `audit.witness.yaml`)'


def write_audit(audit: dict, out_dir: str | pathlib.Path, heatmap, scene) -> dict[str, str]:
    """Write ``audit.json``, ``audit.md``, ``audit_slices.png`` (heatmap slices through the first
    box, boxes numbered in pick order), ``audit_psr.png`` and the task's witness
    (``audit.witness.yaml``, when one was found); returns the paths by name."""
    import json

    from advocc_ros.evaluation.figures import plot_audit_psr, plot_heatmap_slices
    from advocc_ros.fileio import atomic_write_text
    from advocc_ros.model.scene import make_box, save_yaml_atomic

    out = pathlib.Path(out_dir)
    names = ('audit.json', 'audit.md', 'audit_slices.png', 'audit_psr.png')
    paths = {name: out / name for name in names}
    atomic_write_text(paths['audit.json'], json.dumps(audit, indent=1) + '\n')
    atomic_write_text(paths['audit.md'], audit_markdown(audit))
    if audit.get('witness') is not None:
        paths['audit.witness.yaml'] = out / 'audit.witness.yaml'
        save_yaml_atomic(paths['audit.witness.yaml'], audit['witness'])
    boxes = tuple(make_box(b['id'], b['center_m'], (b['size_m'],) * 3) for b in audit['boxes'])
    plot_heatmap_slices(heatmap, paths['audit_slices.png'], scene=scene, obstacles=boxes,
                        at_m=audit['boxes'][0]['center_m'] if boxes else None, numbered=True)
    goal_valid = [None] * (_last_m(audit) + 1)
    for b in audit['budgets']:
        goal_valid[b['m']] = b['goal_valid_fraction']
    plot_audit_psr({planner_label(p): c for p, c in audit['psr'].items()}, goal_valid,
                   paths['audit_psr.png'],
                   title=f'{audit["scene"]}: {audit["method_label"]} attack, policy '
                         f'{audit["policy"]}')
    return {k: str(v) for k, v in paths.items()}
