"""The audit: how few boxes make a planner fail one task, and where do they go (SPEC §3b).

Greedy picks are nested (the first m boxes of a budget-K attack are the budget-m attack), so one
attack at the largest budget K and an evaluation of its prefixes m = 0, 1, 2, ... give, per
planner, the PSR curve over the budget and the minimal budget reaching each PSR threshold (the
paper's Table II for one task). The sweep stops after the first m at which every planner is at
PSR 0, or at the last box the attack placed. Trial k uses seed ``seed + k`` at every m, so the
prefixes are compared on the same random numbers. No ROS.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import time
from typing import Any, Callable

from advocc_ros.evaluation.budgets import minimal_budgets

log = logging.getLogger(__name__)

"""PSR thresholds of the minimal-budget table (fractions; Table II's 80/60/40/20/0 %)."""
ANSWER_THRESHOLD = 0.2
"""A planner "fails" the task when its PSR is at most this (the answer's headline)."""
AUDIT_FORMAT = 'advocc_audit'
AUDIT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class AuditConfig:
    """What one audit runs: the attack, the victims and the trials."""

    planners: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1')
    """OMPL planner ids evaluated at every prefix."""
    max_budget: int = 5
    """K: boxes of the one attack whose prefixes are evaluated."""
    trials: int = 10
    """Plan requests per planner and prefix."""
    time_budget_s: float = 5.0
    """Wall-clock budget of one plan request [s] (the paper: 5)."""
    method: str = 'task'
    """Attack method (``advocc_ros.attack.methods.REGISTRY``); greedy ones give nested picks."""
    policy: str = 'paper'
    """Goal policy of the attack: ``paper`` or ``reachable`` (``advocc_ros.attack.goals``)."""
    seed: int = 0
    """Attack seed; trial k of every prefix uses seed ``seed + k``."""
    workers: int = 2
    """Planner processes serving the trials in parallel (keep <= free cores: PT is wall time)."""

    def __post_init__(self):
        if not self.planners:
            raise ValueError('audit: no planners')
        if self.max_budget < 1:
            raise ValueError(f'audit: max budget must be >= 1, got {self.max_budget}')
        if self.trials < 1:
            raise ValueError(f'audit: trials must be >= 1, got {self.trials}')
        if not self.time_budget_s > 0:
            raise ValueError(f'audit: time budget must be > 0 s, got {self.time_budget_s}')
        if self.workers < 1:
            raise ValueError(f'audit: workers must be >= 1, got {self.workers}')


def planner_label(planner_id: str) -> str:
    """``RRTConnect``, ``PRM*``, ``BKPIECE1``: the OMPL class name, ``star`` as ``*``."""
    from advocc_ros.planning import planner_class_name

    name = planner_class_name(planner_id) or planner_id
    return name.replace('star', '*')


def _row(result: dict) -> dict:
    keys = ('psr', 'successes', 'trials', 'internal_errors', 'pt', 'smr', 'cmr', 'jds',
            'failures')
    return {k: result[k] for k in keys}


def run_audit(scene, heatmap, cfg: AuditConfig = AuditConfig(),
              progress: Callable[[int, str, dict], None] | None = None,
              attack_cfg=None, planning_config=None) -> dict[str, Any]:
    """One attack at budget ``cfg.max_budget`` on ``scene``'s task, then every prefix m = 0, 1,
    ... evaluated per planner (see the module docstring); returns the JSON-able audit.

    ``progress(m, planner, row)`` is called after each evaluation. Raises ``ValueError`` when the
    attack cannot run (its status and message) or the scene has no start or goal.
    """
    import numpy as np

    from advocc_ros.attack import AttackConfig, attack
    from advocc_ros.attack.goals import goal_samples
    from advocc_ros.attack.methods import REGISTRY
    from advocc_ros.evaluation.runner import evaluate_planner
    from advocc_ros.evaluation.perf import machine
    from advocc_ros.model import load_robot, start_configuration

    if scene.goal is None or scene.start is None:
        raise ValueError(f'scene {scene.name!r} needs a start and a goal to be audited')
    if cfg.method not in REGISTRY:
        raise ValueError(f'unknown attack method {cfg.method!r}; known: {list(REGISTRY)}')
    attack_cfg = attack_cfg or AttackConfig()
    t_start = time.perf_counter()
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    result = attack(heatmap, robot, scene.objects, q_init, scene.goal, cfg.max_budget,
                    cfg.method, attack_cfg, seed=cfg.seed, goal_policy=cfg.policy)
    if not result.status.ok:
        raise ValueError(f'attack {cfg.method} failed: {result.status.value}: {result.message}')
    boxes = result.obstacles
    centers = result.centers_m
    samples = goal_samples(robot, scene.objects, scene.goal)
    log.info('audit %s: %d boxes (%s), evaluating prefixes', scene.name, len(boxes),
             result.status.value)

    budgets, psr = [], {p: [] for p in cfg.planners}
    stop_reason = f'evaluated every prefix up to the {len(boxes)} boxes placed'
    for m in range(len(boxes) + 1):
        attacked = scene.with_objects(boxes[:m])
        entry = {'m': m, 'goal_valid_fraction':
                 samples.valid_fraction(centers[:m], result.box_size_m), 'planners': {}}
        for planner in cfg.planners:
            row = evaluate_planner(attacked, planner, cfg.trials, cfg.time_budget_s,
                                   seed=cfg.seed, workers=cfg.workers,
                                   planning_config=planning_config)
            entry['planners'][planner] = _row(row)
            psr[planner].append(row['psr'])
            if progress:
                progress(m, planner, entry['planners'][planner])
        budgets.append(entry)
        if all(entry['planners'][p]['psr'] == 0 for p in cfg.planners):
            stop_reason = f'every planner at PSR 0 % with m = {m}'
            break

    return {
        'format': AUDIT_FORMAT, 'version': AUDIT_VERSION,
        'scene': scene.name, 'scene_hash': scene.objects_hash(),
        'method': cfg.method, 'method_label': REGISTRY[cfg.method].label, 'policy': cfg.policy,
        'max_budget': cfg.max_budget,
        'settings': dict(dataclasses.asdict(cfg), planners=list(cfg.planners),
                         box_size_m=result.box_size_m,
                         heatmap={k: heatmap.meta.get(k) for k in
                                  ('valid_samples', 'scene_name', 'build_s')}),
        'attack': {'status': result.status.value, 'message': result.message,
                   'compute_ms': round(result.compute_s * 1e3, 3),
                   'total_mass': float(result.total_mass),
                   'goal_valid_fraction': result.goal_valid_fraction, 'stats': result.stats},
        'boxes': [{'pick': i + 1, 'id': obj.id,
                   'center_m': [round(float(v), 4) for v in np.asarray(c)],
                   'size_m': result.box_size_m, 'mass': float(mass)}
                  for i, (obj, c, mass) in enumerate(zip(boxes, centers, result.masses))],
        'budgets': budgets,
        'psr': psr,
        'min_budget': minimal_budgets(psr),
        'stopped': stop_reason,
        'wall_s': round(time.perf_counter() - t_start, 2),
        'machine': machine(),
    }


# --------------------------------------------------------------------------------------------
# Report

def _pct(value: float | None) -> str:
    return 'N/A' if value is None else f'{100 * value:.0f} %'


def _boxes(m: int | None) -> str:
    return f'{m} box' if m == 1 else f'{m} boxes'


def _failures(row: dict) -> str:
    counts = dict(row['failures'], **{'internal errors': row.get('internal_errors', 0)})
    text = ', '.join(f'{n} {mode}' for mode, n in counts.items() if n)
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
            low = min(range(len(curve)), key=lambda i: (curve[i] is None, curve[i]))
            lines.append(f'- {label} does not fail (PSR > 20 %) with up to '
                         f'{_boxes(evaluated)}: lowest PSR {_pct(curve[low])} at m = {low} '
                         f'(unattacked {_pct(curve[0])}).')
            continue
        row = audit['budgets'][m]['planners'][planner]
        text = (f'- {label} fails (PSR <= 20 %) with {_boxes(m)}: PSR {_pct(curve[0])} -> '
                f'{_pct(curve[m])} ({_failures(row)})')
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
            cells += [_pct(row['psr']), _failures(row)]
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

    from advocc_ros.bench.figures import plot_audit_psr, plot_heatmap_slices
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
