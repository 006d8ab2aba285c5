"""``advocc evaluate``: run a planner N times on a scene (optionally attacked) and report metrics.

Prints the paper's row (PSR, SMR x10^-2, CMR x10^-2, JDS, PT), the internal errors (left out of
PSR, with a warning on stderr), PSR given goals (over the trials whose goal list, searched
before the clock, has a goal; ``no_goal_found`` counts the others, ``goal_attempts`` per trial)
and the time to first solution (median, p90, PSR at 1/2/5/30 s
within the budget) or, with ``--json``, a JSON object with the row and every trial's record
(each with its ``first_solution_s``). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from advocc_ros.cli import UserError
from advocc_ros.commands.common import (add_scene_args, add_victim_args, describe,
                                        refuse_invalid_task, scene_from_args,
                                        victim_config_from_args)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'evaluate', help='plan N times with an OMPL planner and report PSR/SMR/CMR/JDS/PT',
        description=describe(__doc__))
    add_scene_args(p)
    p.add_argument('--obstacles', help='obstacles YAML (an attack result: objects: [...])')
    p.add_argument('--planner', default='rrtconnect',
                   help='rrtconnect | prmstar | bkpiece1 | another OMPL geometric planner | '
                        'an outside victim: mplib (docs/transfer.md)')
    add_victim_args(p)
    p.add_argument('--trials', type=int, default=20, help='plan requests (default 20)')
    p.add_argument('--time', type=float, default=5.0, help='budget per request [s] (default 5)')
    p.add_argument('--seed', type=int, default=0, help='trial k uses seed SEED + k')
    p.add_argument('--workers', type=int, default=1,
                   help='planner processes in parallel (default 1; PT is wall time, so keep '
                        'workers <= free cores)')
    p.add_argument('--no-simplify', action='store_true',
                   help='return the raw planner path (default: simplify like MoveIt)')
    p.add_argument('--json', action='store_true', help='print JSON (row and per-trial records)')
    p.set_defaults(func=run)


def load_task(args, obstacles: str | None):
    """The scene of ``--scene/--request/--goal-tol`` with the obstacles file's objects added."""
    from advocc_ros.model.scene import objects_from_data, read_yaml

    scene = scene_from_args(args)
    if scene.goal is None or scene.start is None:
        raise UserError(f'{args.scene}: the scene needs a start and a goal to be evaluated')
    if obstacles:
        path = pathlib.Path(obstacles)
        data = read_yaml(path)
        if not isinstance(data, dict) or 'objects' not in data:
            raise UserError(f'{path}: expected a mapping with an objects: list')
        scene = scene.with_objects(objects_from_data(data['objects'], f'{path}.objects',
                                                     path.parent))
    return scene


def run(args: argparse.Namespace) -> int:
    """``advocc evaluate``: the checked task, the trials with a progress bar, the row."""
    import dataclasses

    from advocc_ros.evaluation.outcomes import INTERNAL_ERROR, internal_error_warning, outcome
    from advocc_ros.evaluation.runner import evaluate_planner
    from advocc_ros.planning.types import PlanningConfig

    _check_args(args)
    scene = load_task(args, args.obstacles)
    refuse_invalid_task(scene, args.scene)
    config = dataclasses.replace(PlanningConfig(), simplify=not args.no_simplify)
    victim_config = victim_config_from_args(args, config)

    from advocc_ros.progress import progress_bar
    bar = progress_bar(args.trials, f'{scene.name} {args.planner}', 'plan', file=sys.stderr)
    counts = [0, 0]  # successes, trials that are not internal errors

    def progress(record) -> None:
        counts[0] += record.success
        counts[1] += outcome(record.status) != INTERNAL_ERROR
        bar.update(1)
        if counts[1]:
            bar.set_postfix(psr=f'{counts[0] / counts[1]:.2f}')

    try:
        result = evaluate_planner(scene, args.planner, args.trials, args.time, args.seed,
                                  args.workers, progress=progress, victim_config=victim_config)
    finally:
        bar.close()
    result['obstacles'] = args.obstacles
    result['objects'] = len(scene.objects)
    warning = internal_error_warning(result)
    if warning:
        print(warning, file=sys.stderr)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        _print_row(result, scene.name, args.planner, args.time)
    return 0


def _check_args(args: argparse.Namespace) -> None:
    """Refuse trials, a time budget or workers out of range and an unknown planner."""
    from advocc_ros.limits import MAX_TRIALS
    from advocc_ros.planning.types import PlanningConfig
    from advocc_ros.planning.victims import is_victim, victim_names

    if not 1 <= args.trials <= MAX_TRIALS:
        raise UserError(f'--trials must be in 1..{MAX_TRIALS}')
    if not 0 < args.time <= PlanningConfig().max_time_budget_s:
        raise UserError(f'--time must be in (0, {PlanningConfig().max_time_budget_s:g}]')
    if not is_victim(args.planner):
        raise UserError(f'unknown planner {args.planner!r}; outside victims: {victim_names()}')
    if args.workers < 1:
        raise UserError('--workers must be >= 1')


def _print_row(result: dict, scene_name: str, planner: str, time_s: float) -> None:
    """The paper's row with the internal errors, PSR given goals and time to first solution."""
    from advocc_ros.evaluation.metrics import format_value

    w = max(14, len(scene_name) + 2)
    print(f'{"scene":<{w}}{"planner":<12}{"PSR":>7}{"SMR":>8}{"CMR":>8}{"JDS":>8}{"PT":>8}'
          f'{"errors":>8}')
    print(f'{scene_name:<{w}}{planner:<12}{format_value(result["psr"]):>7}'
          f'{format_value(result["smr"]):>8}{format_value(result["cmr"]):>8}'
          f'{format_value(result["jds"]):>8}{format_value(result["pt"]):>8}'
          f'{result["internal_errors"]:>8}')
    print(f'PSR given goals {format_value(result["psr_given_goals"])} over the trials with a '
          f'goal found before the clock; no goal found: {result["no_goal_found"]} of '
          f'{result["trials"]} (IK attempts per trial: {result["goal_attempts"]})')
    psr_at = ', '.join(f'PSR@{t} s {format_value(v, 2)}' for t, v in result['psr_at'].items())
    print(f'time to first solution (failures at {time_s:g} s): median '
          f'{format_value(result["first_solution_median_s"])} s, p90 '
          f'{format_value(result["first_solution_p90_s"])} s' + (f'; {psr_at}' if psr_at else ''))
