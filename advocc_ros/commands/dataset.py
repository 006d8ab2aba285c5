"""``advocc dataset build``: a certified hard-problem data set from MotionBenchMaker problems,
one Ray task per problem (a local Ray by default, a cluster with ``--ray-address``);
``advocc dataset summary``: the summary of what a build folder holds (a build in progress or
stopped included); ``advocc dataset check``: every exported witness asked again from its files
(the certificate, and MPlib's own collision check).

Per problem: the task check, the witness, the ``task`` attack under the ``solvable`` policy at
each budget, the continuous certificate, the victims on the unattacked and the attacked
problem, and the attacked problem exported in MotionBenchMaker's format with its
``hardness.json``; per data set ``summary.json``, ``summary.md``, ``summary.png``,
``problems.csv``, ``build.json`` (the settings, and one entry per run) and ``logs/``. Every record
names its making (commit, host, CPU, CPUs held, load, versions, times). Running it again on the
same ``--out`` resumes: finished problems are not redone, and a larger ``--limit`` adds problems
to those chosen before. docs/dataset.md has the details.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_task_option_arg, describe, task_options_from_args


def register(sub: argparse._SubParsersAction) -> None:
    group = sub.add_parser('dataset', help='certified hard-problem data sets (MotionBenchMaker '
                           'problems, attacked and measured, on Ray)', description=describe(
                               __doc__))
    verbs = group.add_subparsers(dest='verb', required=True)
    _add_build(verbs.add_parser('build', help='build or resume a data set',
                                description=describe(__doc__)))
    p = verbs.add_parser('summary', help='write the summary of a build folder again (what it '
                         'holds so far)', description=describe(__doc__))
    p.add_argument('out', metavar='DIR', help='a build\'s output folder (--out)')
    p.add_argument('--json', action='store_true', help='print the summary as JSON')
    p.set_defaults(func=_summary)
    p = verbs.add_parser('check', help='ask every exported witness again, from its files: the '
                         'certificate (coal) and MPlib\'s own collision check',
                         description=describe(__doc__))
    p.add_argument('out', metavar='DIR', help='a build\'s output folder (--out), or one '
                   'extracted from a published archive')
    p.add_argument('--checkers', default='coal,mplib', metavar='A,B',
                   help='coal (the continuous certificate; always run) and mplib (FCL on '
                   'MPlib\'s model, in its own venv; default %(default)s)')
    p.add_argument('--csv', metavar='FILE', help='where the rows go (default DIR/'
                   'witness_checks.csv; the counts beside it, as .json)')
    p.set_defaults(func=_check)


def _add_build(p: argparse.ArgumentParser) -> None:
    """The arguments of ``advocc dataset build``: selection, attack and victims, the run."""
    from advocc_ros.dataset.driver import RunConfig
    from advocc_ros.dataset.job import BuildConfig
    from advocc_ros.dataset.problems import SPLITS, TRAIN_LAST

    build, run = BuildConfig(), RunConfig()
    p.add_argument('--problems', required=True, metavar='DIR',
                   help='folder of family folders (box_panda/sceneNNNN.yaml + requestNNNN.yaml)')
    p.add_argument('--out', required=True, metavar='DIR', help='output folder (resumed when it '
                   'holds a build with the same settings)')
    p.add_argument('--families', metavar='A,B', help='families to build (folder names, the '
                   '_panda suffix optional; default: every family folder)')
    p.add_argument('--split', choices=SPLITS, default='all',
                   help=f'train: problems 1-{TRAIN_LAST} of each family, test: the rest '
                   '(default %(default)s)')
    p.add_argument('--limit', type=int, metavar='N', help='the first N problems of each family '
                   'that the goal form poses, in a seeded order of the split (--seed), and '
                   'those before them it refuses: a larger N keeps the smaller\'s')
    p.add_argument('--budgets', default=','.join(map(str, build.budgets)), metavar='M,M',
                   help='boxes per attack, each attacked on its own (default %(default)s)')
    p.add_argument('--victims', default=','.join(build.victims), metavar='A,B',
                   help='planners measured: OMPL ids, mplib, trajopt (default %(default)s)')
    p.add_argument('--trials', type=int, default=build.trials,
                   help='plan requests per victim and budget (default %(default)s)')
    p.add_argument('--time', type=float, default=build.time_s,
                   help='budget per plan request [s] (default %(default)s)')
    p.add_argument('--seed', type=int, default=0, help='selection, attack and trial seed '
                   '(trial k uses SEED + k) (default %(default)s)')
    p.add_argument('--goal-form', choices=GOAL_FORM_CHOICES, default='both',
                   help='how each request\'s joint goal is posed: joint (the configuration '
                   'itself), region (the paper\'s region around its hand pose, --goal-tol) or '
                   'both, each a data set of its own in OUT/joint and OUT/region (one form: '
                   'OUT itself) (default %(default)s)')
    p.add_argument('--goal-tol', metavar='TOL', help='goal region around a joint goal in the '
                   'region form: "pos=X;rot=R" (default pos=0.02;rot=0.1)')
    p.add_argument('--victim-margin', type=float, default=build.victim_margin_m, metavar='M',
                   help='distance the boxes keep from the witness (and a joint goal) beyond the '
                   'certificate\'s guard margin, and from the scene the kept witness is '
                   'chosen for [m] (default %(default)g)')
    p.add_argument('--escape-rays', type=int, default=build.escape_rays, metavar='N',
                   help='joint form: RRT steps from the goal each certified attack\'s escape '
                   'share p is measured on, at the victims\' step (0: none) (default %(default)s)')
    add_task_option_arg(p, tuple(f'{k}={v}' for k, v in build.task_options))
    p.add_argument('--heatmap', metavar='FILE', help='robot-only heatmap to attack with '
                   '(default: built once per robot into OUT/heatmaps/)')
    p.add_argument('--heatmap-samples', type=int, default=run.heatmap_samples,
                   help='samples of the robot-only heatmap built (default %(default)s)')
    p.add_argument('--ray-address', metavar='HOST:PORT', help='a running Ray cluster (ray '
                   'start --head); default: a local Ray started here, on the loopback address')
    p.add_argument('--max-retries', type=int, default=run.max_retries,
                   help='runs of a problem again after its worker died (default %(default)s)')
    p.add_argument('--cpus-per-problem', type=float, default=run.cpus_per_problem,
                   help='Ray CPUs each problem holds; its threads are capped at them (default '
                   '%(default)g: the victims\' times share no CPU with the build; fewer is '
                   'recorded as shared)')
    p.add_argument('--problem-timeout', type=float, default=run.problem_timeout_s,
                   metavar='SECONDS', help='a problem still running this long is cancelled '
                   'and recorded as timeout (default %(default)g s)')
    p.add_argument('--json', action='store_true', help='print the build record as JSON')
    p.set_defaults(func=_build)


GOAL_FORM_CHOICES = ('joint', 'region', 'both')
MAX_ESCAPE_RAYS = 10_000_000
"""Most rays ``--escape-rays`` may ask for (a few minutes of collision checks)."""


def form_folders(out: str, goal_form: str) -> list[tuple[str, str]]:
    """(goal form, its build folder) of ``--goal-form``: ``OUT`` for one form, ``OUT/joint``
    and ``OUT/region`` for both, so the two data sets never mix."""
    import pathlib

    if goal_form != 'both':
        return [(goal_form, out)]
    return [(form, str(pathlib.Path(out) / form)) for form in ('joint', 'region')]


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(',') if v.strip())
    except ValueError:
        raise UserError(f'--{what} {text!r}: expected comma-separated integers') from None
    if not values:
        raise UserError(f'--{what}: give at least one value')
    return values


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(dict.fromkeys(v.strip() for v in (text or '').split(',') if v.strip()))


def _config(args: argparse.Namespace):
    """The ``BuildConfig`` and ``RunConfig`` of the arguments, checked."""
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.task import TaskOptions
    from advocc_ros.dataset.driver import RunConfig
    from advocc_ros.dataset.job import BuildConfig
    from advocc_ros.limits import MAX_TRIALS
    from advocc_ros.formats.mbm_request import parse_goal_tolerance
    from advocc_ros.planning.types import PlanningConfig
    from advocc_ros.planning.victims import is_victim, victim_names

    budgets = _ints(args.budgets, 'budgets')
    top = AttackConfig().max_budget
    if any(not 1 <= b <= top for b in budgets):
        raise UserError(f'--budgets {args.budgets}: each must be in 1..{top}')
    victims = _names(args.victims)
    unknown = [v for v in victims if not is_victim(v)]
    if not victims or unknown:
        raise UserError(f'--victims: unknown {unknown or "(none given)"}; OMPL planner ids '
                        f'(rrtconnect, prmstar, bkpiece1, ...) or {victim_names()}')
    if not 1 <= args.trials <= MAX_TRIALS:
        raise UserError(f'--trials must be in 1..{MAX_TRIALS}')
    if not 0 < args.time <= PlanningConfig().max_time_budget_s:
        raise UserError(f'--time must be in (0, {PlanningConfig().max_time_budget_s:g}]')
    if args.goal_tol:
        parse_goal_tolerance(args.goal_tol)  # ValueError naming the field
    options = task_options_from_args(args, 'task')
    given = () if options is None else tuple(
        (k, v) for k, v in dataclasses.asdict(options).items()
        if v != getattr(TaskOptions(), k))
    if not 0 <= args.escape_rays <= MAX_ESCAPE_RAYS:
        raise UserError(f'--escape-rays must be in 0..{MAX_ESCAPE_RAYS}')
    if not 0 <= args.victim_margin <= 0.05:
        raise UserError('--victim-margin must be in [0, 0.05] m')
    if args.max_retries < 0 or args.cpus_per_problem <= 0 or args.heatmap_samples < 1 \
            or not args.problem_timeout > 0:
        raise UserError('--max-retries must be >= 0, --cpus-per-problem > 0, '
                        '--heatmap-samples >= 1 and --problem-timeout > 0')
    build = BuildConfig(budgets=tuple(sorted(set(budgets))), victims=victims,
                        trials=args.trials, time_s=args.time, seed=args.seed,
                        task_options=given, goal_tol=args.goal_tol,
                        victim_margin_m=args.victim_margin, escape_rays=args.escape_rays)
    run = RunConfig(ray_address=args.ray_address, max_retries=args.max_retries,
                    cpus_per_problem=args.cpus_per_problem,
                    problem_timeout_s=args.problem_timeout,
                    heatmap_samples=args.heatmap_samples, heatmap_file=args.heatmap)
    return build, run


def _summary(args: argparse.Namespace) -> int:
    import pathlib

    from advocc_ros.dataset import store
    from advocc_ros.dataset.summary import markdown, write_summary

    out = pathlib.Path(args.out)
    if not (out / store.BUILD_FILE).is_file():
        raise UserError(f'{out}: not a data set build folder (no {store.BUILD_FILE})')
    summary = write_summary(out)
    print(json.dumps(summary, indent=1) if args.json else markdown(summary))
    return 0


def _check(args: argparse.Namespace) -> int:
    import pathlib

    from advocc_ros.dataset.checks import (CHECKERS, CHECKS_FILE, COLUMNS, check_folder,
                                           counts, exported)
    from advocc_ros.dataset.summary import csv_text
    from advocc_ros.evaluation import provenance
    from advocc_ros.fileio import atomic_write_text

    out = pathlib.Path(args.out)
    checkers = _names(args.checkers)
    unknown = sorted(set(checkers) - set(CHECKERS))
    if unknown:
        raise UserError(f'--checkers: unknown {unknown}; known: {", ".join(CHECKERS)}')
    if not any(out.glob('*/*/hardness.json')):
        raise UserError(f'{out}: no problem of a data set build (no FAMILY/NNNN/hardness.json)')
    todo = sum(1 for _ in exported(out))
    started, rows = provenance.now(), []
    for row in check_folder(out, tuple(checkers)):
        rows.append(row)
        print(f'checked {len(rows)}/{todo}: {row["family"]}/{row["problem"]} M={row["budget"]}',
              file=sys.stderr, flush=True)
    target = pathlib.Path(args.csv) if args.csv else out / CHECKS_FILE
    atomic_write_text(target, csv_text(rows, COLUMNS))
    tally = dict(counts(rows), made=dict(provenance.record(), started=started,
                                         finished=provenance.now()))
    atomic_write_text(target.with_suffix('.json'), json.dumps(tally, indent=1) + '\n')
    line = f'{len(rows)} exported witnesses: {tally["certified"]} certified (coal)'
    if tally['unreadable']:
        line += f', {tally["unreadable"]} unreadable'
    if tally['mplib_errors']:
        line += f', {tally["mplib_errors"]} MPlib could not answer'
    if tally['mplib_accepted'] is not None:
        line += f', {tally["mplib_accepted"]} accepted by MPlib'
    print(f'{line} -> {target} (counts: {target.with_suffix(".json")})')
    for r in rows:
        if r['certificate'] != 'certified' or r.get('mplib_accepted') is False or \
                r.get('mplib_error'):
            print(f'  {r["family"]}/{r["problem"]} M={r["budget"]}: {r["certificate"]}'
                  + (f', MPlib: {r["mplib_colliding"]} of {r["mplib_states"]} states collide'
                     if r.get('mplib_accepted') is False else '')
                  + (f', MPlib: {r["mplib_error"]}' if r.get('mplib_error') else '')
                  + (f' ({r["message"]})' if r['message'] else ''))
    return 1 if tally['unreadable'] or tally['mplib_errors'] else 0


def _build(args: argparse.Namespace) -> int:
    from advocc_ros.dataset.driver import Cluster, Selection, build

    config, run = _config(args)
    selection = Selection(args.problems, _names(args.families) or None, args.split, args.limit,
                          args.seed)
    entries = {}
    with Cluster(run) as cluster:  # one Ray for both forms
        for form, out in form_folders(args.out, args.goal_form):
            entries[form] = build(selection, out, dataclasses.replace(config, goal_form=form),
                                  run, cluster=cluster)
            if not args.json:
                _print_build(out, entries[form])
    if args.json:
        print(json.dumps(entries, indent=1))
    return 0


def _print_build(out: str, entry: dict) -> None:
    """A build's lines on the terminal: counts, the share beaten per split, timing, errors."""
    summary = entry['summary']
    print(f'{out}: {summary["problems"]} of {summary["selected"]} selected problems '
          'recorded; this run: '
          + (', '.join(f'{v} {k}' for k, v in entry.get('counts', {}).items())
             or 'nothing to do') + f' in {entry["wall_s"]:.0f} s')
    for g in summary['groups']:
        if g['family'] != 'all':
            continue
        beaten = ', '.join(
            f'M={b}: {cell["all_victims_psr_le_20"] * 100:.0f} % of {cell["evaluated"]}'
            for b, cell in g['budgets'].items() if cell['all_victims_psr_le_20'] is not None)
        print(f'  {g["split"]}: {g["outcomes"]["built"]} of {g["problems"]} built; every '
              f'victim at PSR <= 20 %: {beaten or "none evaluated"}')
    print(f'  {entry["timing"]["note"]}')
    for line in summary['errors']:
        print(f'  not finished: {line}', file=sys.stderr)
    print(f'  see {out}/summary.md')
