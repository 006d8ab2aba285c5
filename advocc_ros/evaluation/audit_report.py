"""An audit's report: the answer, the per-budget table, ``audit.md``, ``audit.json`` and the
figures (``advocc_ros.evaluation.audit`` computes the audit). No ROS."""

from __future__ import annotations

import pathlib

from advocc_ros.evaluation.audit import ANSWER_THRESHOLD


def planner_label(planner_id: str) -> str:
    """``RRTConnect``, ``PRM*``, ``BKPIECE1``: the OMPL class name, ``star`` as ``*``."""
    from advocc_ros.planning import planner_class_name

    name = planner_class_name(planner_id) or planner_id
    return name.replace('star', '*')


def _pct(value: float | None) -> str:
    return 'N/A' if value is None else f'{100 * value:.0f} %'


def _boxes(m: int | None) -> str:
    return f'{m} box' if m == 1 else f'{m} boxes'


def _failures(failures: dict) -> str:
    text = ', '.join(f'{n} {mode}' for mode, n in failures.items() if n)
    return text or '-'


def audit_answer(audit: dict) -> str:
    """The headline: per planner, how many boxes make it fail (PSR <= 20 %) and reach 0 %."""
    s = audit['settings']
    lines = [f'Audit of {audit["scene"]}: attack {audit["method_label"]} (goal policy '
             f'{audit["policy"]}, {s["box_size_m"]} m boxes, up to {audit["max_budget"]}), '
             f'{s["trials"]} trials x {s["time_budget_s"]:g} s per planner and budget.']
    fail, zero = audit['min_budget'][str(ANSWER_THRESHOLD)], audit['min_budget'][str(0.0)]
    evaluated = len(audit['budgets']) - 1
    for planner, curve in audit['psr'].items():
        label = planner_label(planner)
        m = fail[planner]
        if m is None:
            low = min(range(len(curve)), key=lambda i: curve[i])
            lines.append(f'- {label} does not fail (PSR > 20 %) with up to '
                         f'{_boxes(evaluated)}: lowest PSR {_pct(curve[low])} at m = {low} '
                         f'(unattacked {_pct(curve[0])}).')
            continue
        row = audit['budgets'][m]['planners'][planner]
        text = (f'- {label} fails (PSR <= 20 %) with {_boxes(m)}: PSR {_pct(curve[0])} -> '
                f'{_pct(curve[m])} ({_failures(row["failures"])})')
        if zero[planner] is not None and zero[planner] != m:
            text += f'; PSR 0 % with {_boxes(zero[planner])}'
        lines.append(text + '.')
    placed = ', '.join(f'#{b["pick"]} at {b["center_m"]}' for b in audit['boxes'][:evaluated])
    if placed:
        lines.append(f'Boxes (robot base frame, pick order): {placed}.')
    lines.append('Goal poses left valid: ' + ', '.join(
        f'm={b["m"]}: {_pct(b["goal_valid_fraction"])}' for b in audit['budgets'])
        + f'. Stopped: {audit["stopped"]}.')
    return '\n'.join(lines)


def budget_table(audit: dict) -> str:
    """Markdown: per m, goal-valid fraction, and per planner PSR and failure modes."""
    planners = list(audit['psr'])
    head = ['m', 'goal valid'] + [f'{planner_label(p)} {c}' for p in planners
                                  for c in ('PSR', 'failures')]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for b in audit['budgets']:
        cells = [str(b['m']), _pct(b['goal_valid_fraction'])]
        for p in planners:
            row = b['planners'][p]
            cells += [_pct(row['psr']), _failures(row['failures'])]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def audit_markdown(audit: dict) -> str:
    """The whole ``audit.md``: answer, per-budget table, minimal budgets, boxes, settings."""
    s, planners = audit['settings'], list(audit['psr'])
    thresholds = list(audit['min_budget'])
    out = [f'# Audit: {audit["scene"]}', '', '## Answer', '', audit_answer(audit), '',
           '## PSR per budget', '', budget_table(audit), '',
           '## Minimal budget per PSR threshold', '',
           '| planner | ' + ' | '.join(f'PSR <= {float(t) * 100:.0f} %' for t in thresholds)
           + ' |', '|' + '---|' * (1 + len(thresholds))]
    for p in planners:
        cells = [audit['min_budget'][t][p] for t in thresholds]
        out.append(f'| {planner_label(p)} | '
                   + ' | '.join(f'> {len(audit["budgets"]) - 1}' if c is None else str(c)
                                for c in cells) + ' |')
    evaluated = len(audit['budgets']) - 1
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
            f'- planners: {", ".join(planners)}; {s["trials"]} trials, '
            f'{s["time_budget_s"]:g} s per plan, {s["workers"]} worker processes',
            f'- heatmap: {s["heatmap"]["valid_samples"]} samples, built for '
            f'{s["heatmap"]["scene_name"]}',
            f'- wall time: {audit["wall_s"]} s (attack, then the evaluations) on '
            f'{audit["machine"]["cpu"]} ({audit["machine"]["cores"]} cores), Python '
            f'{audit["machine"]["python"]}', '']
    return '\n'.join(out)


def write_audit(audit: dict, out_dir: str | pathlib.Path, heatmap, scene) -> dict[str, str]:
    """Write ``audit.json``, ``audit.md``, ``audit_slices.png`` (heatmap slices through the first
    box, boxes numbered in pick order) and ``audit_psr.png``; returns the paths by name."""
    import json

    from advocc_ros.evaluation.figures import plot_audit_psr, plot_heatmap_slices
    from advocc_ros.fileio import atomic_write_text
    from advocc_ros.model import make_box

    out = pathlib.Path(out_dir)
    names = ('audit.json', 'audit.md', 'audit_slices.png', 'audit_psr.png')
    paths = {name: out / name for name in names}
    atomic_write_text(paths['audit.json'], json.dumps(audit, indent=1) + '\n')
    atomic_write_text(paths['audit.md'], audit_markdown(audit))
    boxes = tuple(make_box(b['id'], b['center_m'], (b['size_m'],) * 3) for b in audit['boxes'])
    plot_heatmap_slices(heatmap, paths['audit_slices.png'], scene=scene, obstacles=boxes,
                        at_m=audit['boxes'][0]['center_m'] if boxes else None, numbered=True)
    plot_audit_psr({planner_label(p): c for p, c in audit['psr'].items()},
                   [b['goal_valid_fraction'] for b in audit['budgets']], paths['audit_psr.png'],
                   title=f'{audit["scene"]}: {audit["method_label"]} attack, policy '
                         f'{audit["policy"]}')
    return {k: str(v) for k, v in paths.items()}
