"""``advocc audit``: how few boxes make each planner fail this task, and where do they go?

One attack at the largest budget K, then its prefixes m = 0, 1, 2, ... (``--prefixes``: only
those) evaluated per planner (greedy picks are nested) until every planner is at PSR 0 %
(``--target-psr P``: each planner until its PSR is <= P %); every evaluated prefix gets a
verdict (certified solvable / goal blocked / unknown). The answer: how few boxes make the pick
impossible (goal blocked, from a paper-policy attack) and how few make each planner fail while
the task stays certified solvable (``--policy solvable`` runs that attack too). Writes
``DIR/audit.md``, ``DIR/audit.json``, two figures and ``DIR/audit.html`` (an offline 3D
view); prints the answer and the per-budget table (``--json``: the audit as JSON). Progress
goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

from advocc_ros.cli import UserError
from advocc_ros.commands.common import (add_attack_args, add_bag_arg, add_scene_args,
                                        add_task_option_arg, check_bag_arg, describe,
                                        refuse_invalid_task, scene_from_args,
                                        task_options_from_args)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('audit', help='how few boxes make each planner fail this task',
                       description=describe(__doc__))
    add_scene_args(p)
    p.add_argument('--planners', default='rrtconnect,prmstar,bkpiece1',
                   help='comma-separated OMPL planner ids or outside victims (mplib; '
                        'docs/transfer.md) (default %(default)s)')
    add_attack_args(p)
    add_task_option_arg(p)
    p.add_argument('--max-budget', type=int, default=5, metavar='K',
                   help='boxes of the attack whose prefixes are evaluated (default %(default)s)')
    p.add_argument('--trials', type=int, default=10,
                   help='plan requests per planner and budget (default %(default)s)')
    p.add_argument('--time', type=float, default=5.0,
                   help='budget of one plan request [s] (default %(default)s, the paper\'s)')
    p.add_argument('--heatmap', metavar='FILE',
                   help='heatmap .npz (default: build one into DIR, or reuse it there)')
    p.add_argument('--target-psr', metavar='P',
                   help='PSR in percent (20 or 20%%) at which a planner counts as failed: it is '
                        'not evaluated at later prefixes, and the audit stops once every planner '
                        'got there (default: every planner at every prefix until all are at 0 %%)')
    p.add_argument('--prefixes', metavar='M,M,...',
                   help='evaluate only these prefixes m, e.g. 0,1,2,3,5,7,10,15,20 (0 always; '
                        'default every m); the fewest boxes is then the smallest evaluated m')
    p.add_argument('--workers', type=int, default=2,
                   help='planner processes in parallel (default %(default)s; PT is wall time)')
    p.add_argument('--out', required=True, metavar='DIR', help='output folder')
    add_bag_arg(p)
    p.add_argument('--json', action='store_true', help='print the audit as JSON')
    p.set_defaults(func=run)


def audit_config(args: argparse.Namespace):
    """``AuditConfig`` from the arguments, with the user's errors as ``UserError``."""
    from advocc_ros.attack import load_method
    from advocc_ros.audit.audit import AuditConfig
    from advocc_ros.limits import MAX_TRIALS
    from advocc_ros.planning.types import PlanningConfig
    from advocc_ros.planning.victims import is_victim, victim_names

    planners = tuple(p.strip() for p in args.planners.split(',') if p.strip())
    if not planners:
        raise UserError('--planners: give at least one planner')
    unknown = [p for p in planners if not is_victim(p)]
    if unknown:
        raise UserError(f'unknown planner(s) {unknown}; e.g. rrtconnect, prmstar, bkpiece1, '
                        f'{", ".join(victim_names())}')
    if not 1 <= args.trials <= MAX_TRIALS:
        raise UserError(f'--trials must be in 1..{MAX_TRIALS}, got {args.trials}')
    if not 1 <= args.max_budget <= 100:
        raise UserError(f'--max-budget must be in 1..100, got {args.max_budget}')
    if not 0 < args.time <= PlanningConfig().max_time_budget_s:
        raise UserError(f'--time must be in (0, {PlanningConfig().max_time_budget_s:g}] s')
    if args.workers < 1:
        raise UserError('--workers must be >= 1')
    if not load_method(args.method):
        raise UserError(f'method {args.method!r} is not available in this installation')
    if args.method in ('pfa', 'pfa++'):
        raise UserError(f'--method {args.method} queries planners while placing boxes; the '
                        'audit needs a heatmap method (task, ours, random)')
    return AuditConfig(planners=planners, max_budget=args.max_budget, trials=args.trials,
                       time_budget_s=args.time, method=args.method, policy=args.policy,
                       seed=args.seed, workers=args.workers,
                       target_psr=_target_psr(args.target_psr),
                       prefixes=_prefixes(args.prefixes, args.max_budget),
                       task_options=task_options_from_args(args, args.method))


def _target_psr(text: str | None) -> float | None:
    """``--target-psr`` (percent, as the audit prints PSR) as a fraction."""
    if text is None:
        return None
    try:
        percent = float(text.strip().removesuffix('%').strip())
    except ValueError:
        raise UserError(f'--target-psr: {text!r} is not a number (percent, e.g. 20)') from None
    if not 0 <= percent <= 100:  # NaN too
        raise UserError(f'--target-psr must be in 0..100 (percent), got {text!r}')
    if 0 < percent < 1:
        raise UserError(f'--target-psr is in percent: {text!r} is below one success in 100 '
                        f'trials; for {100 * percent:g} % give {100 * percent:g}')
    return percent / 100


def _prefixes(text: str | None, max_budget: int) -> tuple[int, ...] | None:
    """``--prefixes`` as integers in 0..``max_budget``."""
    if text is None:
        return None
    items = [t.strip() for t in text.split(',') if t.strip()]
    bad = [t for t in items if not t.isdecimal()]
    if bad or not items:
        raise UserError(f'--prefixes: give non-negative integers, e.g. 0,1,2,3,5; got {text!r}')
    beyond = [int(t) for t in items if int(t) > max_budget]
    if beyond:
        raise UserError(f'--prefixes {beyond} exceed --max-budget {max_budget}')
    return tuple(int(t) for t in items)


def audit_heatmap(scene, out: pathlib.Path, heatmap_file: str | None, workers: int,
                  samples: int | None = None, log=print):
    """The heatmap of ``--heatmap``, or ``out/heatmap_<scene>.npz`` (built there if missing, with
    ``samples`` or the default sample count)."""
    from advocc_ros.heatmap import (HeatmapConfig, HeatmapError, build_heatmap, load_heatmap,
                                    save_heatmap)
    from advocc_ros.model.robot import load_robot

    robot_hash = load_robot(scene.robot).hash
    path = pathlib.Path(heatmap_file) if heatmap_file else out / f'heatmap_{scene.name}.npz'
    try:
        if heatmap_file or path.exists():
            heatmap = load_heatmap(path, robot_hash=robot_hash)
            log(f'heatmap: {path}')
            return heatmap
    except HeatmapError as exc:
        raise UserError(str(exc)) from None
    t0 = time.perf_counter()
    cfg = HeatmapConfig() if samples is None else HeatmapConfig(samples=samples)
    heatmap = build_heatmap(scene, cfg, seed=0, workers=workers)
    save_heatmap(heatmap, path)
    log(f'heatmap: built {path} ({cfg.samples} samples) in {time.perf_counter() - t0:.1f} s')
    return heatmap


def run_audit_to(scene, heatmap, cfg, out: pathlib.Path, log=print, attack_cfg=None) -> dict:
    """Run the audit with a progress line per evaluation on stderr and write its files
    (``attack_cfg``: the attack's constants, default ``AttackConfig()``)."""
    from advocc_ros.audit.audit import run_audit
    from advocc_ros.audit.report import planner_label, write_audit
    from advocc_ros.evaluation.outcomes import internal_error_warning

    def progress(m: int, planner: str, row: dict) -> None:
        psr = 'N/A' if row['psr'] is None else f'{100 * row["psr"]:3.0f} %'
        pt = 'N/A' if row['pt'] is None else f'{row["pt"]:.2f} s'
        print(f'  m={m} {planner_label(planner):<11} PSR {psr} '
              f'({row["successes"]}/{row["trials"]}, PT {pt})', file=sys.stderr, flush=True)
        warning = internal_error_warning(row, f'm={m} {planner}')
        if warning:
            print(warning, file=sys.stderr, flush=True)

    audit = run_audit(scene, heatmap, cfg, progress=progress, attack_cfg=attack_cfg)
    paths = write_audit(audit, out, heatmap, scene)
    log(f'audit: {paths["audit.md"]}, {paths["audit.json"]}, figures '
        f'{paths["audit_slices.png"]}, {paths["audit_psr.png"]} ({audit["wall_s"]:.0f} s)')
    from advocc_ros.view.scene_page import write_audit_view
    log(f'3D view: {write_audit_view(out, scene, heatmap)} (open it in a browser)')
    return audit


def run(args: argparse.Namespace) -> int:
    from advocc_ros.audit.report import audit_answer, budget_table

    from advocc_ros.attack import AttackConfig

    cfg = audit_config(args)
    try:
        attack_cfg = AttackConfig(box_size_m=args.size)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    check_bag_arg(args)
    scene = scene_from_args(args)
    if scene.start is None or scene.goal is None:
        raise UserError(f'{args.scene}: the scene needs a start and a goal to be audited')
    refuse_invalid_task(scene, args.scene)  # before the heatmap, the witness, any trial
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda text: print(text, file=sys.stderr)) if args.json else print
    heatmap = audit_heatmap(scene, out, args.heatmap, args.workers, log=log)
    audit = run_audit_to(scene, heatmap, cfg, out, log=log, attack_cfg=attack_cfg)
    if args.bag:
        from advocc_ros.view.scene_page import audit_boxes
        from advocc_ros.ros.bag import write_attack_bag
        log(f'bag: {write_attack_bag(args.bag, scene, audit_boxes(audit), heatmap)}')
    if args.json:
        print(json.dumps(audit, indent=1))
    else:
        print()
        print(audit_answer(audit))
        print()
        print(budget_table(audit))
    return 0
