"""``advocc export``: an attacked task as MotionBenchMaker problem files, so that other planning
stacks can run it: ``sceneNNNN.yaml`` (MoveIt PlanningScene with the boxes),
``requestNNNN.yaml`` (MotionPlanRequest: start state, goal region as constraints) and
``trajectoryNNNN.yaml`` (the witness path, a RobotTrajectory), plus ``export.yaml`` saying
where each problem comes from.

Without ``--variations`` the one problem is the scene with the obstacles file's boxes and its
witness, re-certified first. With ``--variations N`` the folder holds N seeded variations of
the scene (objects jittered as ``advocc scenes vary`` does), each attacked again with the
obstacles file's method, budget and task options (``--task-option`` overrides them) under the
``solvable`` policy: the old boxes were placed for
the old geometry, and only a fresh attack keeps a fresh witness valid. As MotionBenchMaker keeps
only the problems its planner solved, a variation is kept only when its witness is certified
with its boxes; the others are skipped (and listed) and further variations drawn, up to
``--max-draws``. A planner runs once per variation: its witness, one RRTConnect run on the
unattacked variation (``advocc_ros.attack.edges``); the attacks themselves query none.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys

from advocc_ros.cli import UserError
from advocc_ros.commands.common import (add_scene_args, add_task_option_arg, describe,
                                        scene_from_args, task_options_from_args)

MANIFEST = 'export.yaml'


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('export', help='write an attacked task (scene + boxes, request, witness '
                       'trajectory) as MotionBenchMaker problem files',
                       description=describe(__doc__))
    add_scene_args(p)
    p.add_argument('--obstacles', required=True,
                   help='obstacles file of `advocc attack` (its witness beside it as '
                        '<stem>.witness.yaml)')
    p.add_argument('--witness', metavar='FILE', help='witness file (default: beside '
                   '--obstacles)')
    p.add_argument('--out', required=True, help='folder to write the problem files into')
    p.add_argument('--variations', type=int, default=0, metavar='N',
                   help='write N seeded variations, each attacked again (default: the one task)')
    p.add_argument('--seed', type=int, default=0, help='seed of the variations and attacks')
    p.add_argument('--max-draws', type=int, metavar='K',
                   help='variations tried at most for --variations N (default 3 N)')
    p.add_argument('--heatmap', help='heatmap to attack the variations with (default: the '
                   'obstacles file\'s heatmap_file)')
    add_task_option_arg(p)
    p.add_argument('--time', type=float, default=5.0,
                   help='allowed_planning_time written into the requests [s] (default 5)')
    p.add_argument('--json', action='store_true', help='print the manifest as JSON')
    p.set_defaults(func=run)


def _certified(robot, scene, witness) -> str | None:
    """Why ``witness`` is not a solution of ``scene`` (its objects include the boxes), from the
    scene's own start, or None."""
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.planning.witness import certify

    return certify(robot, CollisionWorld(robot, scene.shapes), scene.goal, witness,
                   q_init=start_configuration(scene, robot))[0]


def _write(args, index: int, attacked, robot, witness):
    """The problem files of ``attacked`` with ``witness`` (in the robot's joint order)."""
    from advocc_ros.formats.mbm_export import write_problem

    return write_problem(args.out, index, attacked, robot, robot.joint_names,
                         witness.configurations(robot), args.time)


def _problem_entry(files, scene, boxes, witness, **extra) -> dict:
    return {'scene': files.scene.name, 'request': files.request.name,
            'trajectory': files.trajectory.name, 'name': scene.name,
            'boxes': [o.id for o in boxes], 'waypoints': int(len(witness.waypoints)),
            **extra}


def _export_one(args, scene, robot, boxes) -> dict:
    from advocc_ros.planning.witness import load_witness, witness_file

    path = pathlib.Path(args.witness) if args.witness else witness_file(args.obstacles)
    if not path.is_file():
        raise UserError(f'{path}: no witness file (attack with --policy solvable, or give '
                        '--witness FILE)')
    witness = load_witness(path)
    attacked = scene.with_objects(boxes)
    why = _certified(robot, attacked, witness)
    if why is not None:
        raise UserError(f'{path}: the witness is not a solution with the boxes of '
                        f'{args.obstacles}: {why}')
    files = _write(args, 1, attacked, robot, witness)
    return {'problems': [_problem_entry(files, attacked, boxes, witness, witness_file=str(path))],
            'skipped': []}


def _variation_options(args, meta: dict):
    """The ``TaskOptions`` the variations are attacked with: ``--task-option``, else the
    obstacles file's ``task_options`` (None: not a ``task`` attack)."""
    from advocc_ros.attack.task import task_options

    given = task_options_from_args(args, meta['method'])
    if given is not None or meta['method'] != 'task':
        return given
    try:
        return task_options(meta.get('task_options') or {})
    except ValueError as exc:
        raise UserError(f'{args.obstacles}: {exc}') from None


def _export_variations(args, scene, robot, meta) -> dict:
    """Seeded variations of ``scene``, each attacked again under ``solvable`` (module doc)."""
    from advocc_ros.attack import REGISTRY, AttackConfig
    from advocc_ros.attack.edges import attack_task
    from advocc_ros.heatmap import load_heatmap
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.pose import SceneError
    from advocc_ros.scenes.variations import vary_scene

    heatmap_file = args.heatmap or meta.get('heatmap_file')
    if not heatmap_file:
        raise UserError(f'{args.obstacles} names no heatmap_file; give --heatmap to attack the '
                        'variations')
    binds = [m for m, spec in REGISTRY.items() if not spec.queries_planner]  # not PFA
    if meta.get('method') not in binds or not isinstance(meta.get('budget'), int):
        raise UserError(f'{args.obstacles}: method {meta.get("method")!r} and budget '
                        f'{meta.get("budget")!r}: the variations are attacked again under '
                        f'--policy solvable, which needs one of {binds} and a budget')
    options = _variation_options(args, meta)
    heatmap = load_heatmap(heatmap_file, robot_hash=robot.hash)
    try:
        cfg = AttackConfig(box_size_m=meta.get('box_size_m') or AttackConfig().box_size_m,
                           goal_policy='solvable')
    except ValueError as exc:
        raise UserError(f'{args.obstacles}: {exc}') from None
    draws = args.max_draws or 3 * args.variations
    problems, skipped = [], []
    for index in range(1, draws + 1):
        if len(problems) == args.variations:
            break
        try:
            var = vary_scene(scene, index, args.seed).scene
        except SceneError as exc:
            skipped.append({'variation': index, 'reason': str(exc)})
            continue
        result = attack_task(heatmap, robot, var.objects, start_configuration(var, robot),
                             var.goal, meta['budget'], meta['method'], cfg,
                             seed=args.seed + index, method_options=options)
        verdict = result.solvable
        why = (f'attack {result.status.value}: {result.message}' if not result.status.ok
               else 'not assessed' if verdict is None
               else f'{verdict.verdict} ({verdict.message})' if not verdict.certified
               else _certified(robot, var.with_objects(result.obstacles), result.witness))
        if why is not None:
            skipped.append({'variation': index, 'reason': why})
            print(f'advocc export: variation {index} skipped ({why})', file=sys.stderr)
            continue
        attacked = var.with_objects(result.obstacles)
        files = _write(args, len(problems) + 1, attacked, robot, result.witness)
        problems.append(_problem_entry(files, attacked, result.obstacles, result.witness,
                                       variation=index))
    if len(problems) < args.variations:
        raise UserError(f'only {len(problems)} of {args.variations} variations kept in '
                        f'{draws} draws (skipped: {skipped}); raise --max-draws')
    written = {'problems': problems, 'skipped': skipped, 'heatmap': str(heatmap_file)}
    if options is not None:
        written['task_options'] = dataclasses.asdict(options)
    return written


def run(args: argparse.Namespace) -> int:
    from advocc_ros.attack import load_obstacles
    from advocc_ros.formats.mbm_export import check_exportable
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import save_yaml_atomic

    if args.variations < 0:
        raise UserError('--variations must be >= 0')
    if args.task_option and not args.variations:
        raise UserError('--task-option applies to --variations N (the variations are attacked '
                        'again; without it the obstacles file\'s boxes are exported)')
    if args.max_draws is not None and args.max_draws < args.variations:
        raise UserError('--max-draws must be >= --variations')
    if not 0 < args.time <= 600:
        raise UserError('--time must be in (0, 600]')
    scene = scene_from_args(args)
    check_exportable(scene)
    robot = load_robot(scene.robot)
    boxes, meta = load_obstacles(args.obstacles)
    made_for = (meta.get('scene') or {}).get('objects_hash')
    if made_for not in (None, scene.objects_hash()):
        print(f'advocc export: warning: {args.obstacles} was made for scene '
              f'{meta["scene"].get("name")!r}, not {scene.name!r}', file=sys.stderr)
    out = pathlib.Path(args.out)
    if out.exists() and any(out.glob('scene[0-9]*.yaml')):
        raise UserError(f'{out}: already holds problem files; choose an empty folder')
    if args.variations:
        written = _export_variations(args, scene, robot, meta)
    else:
        written = _export_one(args, scene, robot, boxes)
    manifest = {'format': 'advocc_mbm_export', 'version': 1, 'scene': scene.name,
                'obstacles': str(args.obstacles), 'method': meta.get('method'),
                'budget': meta.get('budget'), 'goal_policy': (
                    'solvable' if args.variations else meta.get('goal_policy')),
                'seed': args.seed, 'variations': args.variations, **written}
    save_yaml_atomic(out / MANIFEST, manifest)
    if args.json:
        print(json.dumps(manifest, indent=1))
    else:
        for entry in written['problems']:
            print(f'{out / entry["scene"]}  {entry["request"]}  {entry["trajectory"]}  '
                  f'({len(entry["boxes"])} boxes, witness of {entry["waypoints"]} waypoints)')
        if written['skipped']:
            print(f'{len(written["skipped"])} variation(s) skipped: see {out / MANIFEST}')
    return 0
