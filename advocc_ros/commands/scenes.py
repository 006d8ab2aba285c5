"""``advocc scenes list|check|convert|vary|sense``: shipped scenes, imports, seeded variations
and simulated sensed clouds."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_scene_args, scene_from_args


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('scenes', help='list, check, convert and vary scenes')
    ssub = parser.add_subparsers(dest='scenes_command', required=True)

    lst = ssub.add_parser('list', help='the scenes shipped in config/scenes')
    lst.add_argument('--json', action='store_true')
    lst.set_defaults(func=_list)

    check = ssub.add_parser('check', help='load a scene (ours or MotionBenchMaker) and check '
                                          'its start and goal region')
    add_scene_args(check)
    check.add_argument('--ik-attempts', type=int, default=400,
                       help='IK attempts to find valid goal configurations (default 400)')
    check.add_argument('--json', action='store_true')
    check.set_defaults(func=_check)

    convert = ssub.add_parser('convert', help='write a scene (e.g. a MotionBenchMaker import) '
                                              'as our scene YAML')
    add_scene_args(convert)
    convert.add_argument('--out', required=True, help='output scene YAML')
    convert.set_defaults(func=_convert)

    vary = ssub.add_parser('vary', help='seeded MotionBenchMaker-like variations of a scene')
    add_scene_args(vary)
    vary.add_argument('--count', type=int, required=True, help='number of variations')
    vary.add_argument('--seed', type=int, default=0, help='variation i depends on (seed, i)')
    vary.add_argument('--out', required=True, help='output folder (NAME_0000.yaml, ...)')
    vary.add_argument('--jitter-pos', type=float, default=0.02,
                      help='half-range of planar object offsets [m] (default %(default)s)')
    vary.add_argument('--jitter-size', type=float, default=0.1,
                      help='half-range of relative size changes (default %(default)s)')
    vary.add_argument('--jitter-yaw', type=float, default=0.1,
                      help='half-range of rotations about the vertical [rad] '
                           '(default %(default)s)')
    vary.add_argument('--fixed', default='table',
                      help='comma-separated id patterns that never move (default %(default)s)')
    vary.add_argument('--rigid', default='shelf_*,bin_*,cage_*',
                      help='comma-separated id patterns; each pattern\'s objects move together '
                           'and keep their size (default %(default)s)')
    vary.add_argument('--target', default='target*',
                      help='id pattern of the object the goal region follows '
                           '(default %(default)s)')
    vary.add_argument('--json', action='store_true')
    vary.set_defaults(func=_vary)

    sense = ssub.add_parser('sense', help='replace a scene\'s objects by one simulated sensed '
                                          'point cloud (NAME_sensed.yaml + .ply)')
    add_scene_args(sense)
    sense.add_argument('--out', required=True, help='output folder')
    sense.add_argument('--spacing', type=float, default=0.005,
                       help='surface sample spacing [m] (default %(default)s)')
    sense.add_argument('--noise', type=float, default=0.001,
                       help='point noise standard deviation [m] (default %(default)s)')
    sense.add_argument('--resolution', type=float, default=0.02,
                       help='octree leaf edge [m] (default %(default)s)')
    sense.add_argument('--seed', type=int, default=0)
    sense.set_defaults(func=_sense)


def _patterns(text: str) -> tuple[str, ...]:
    return tuple(p.strip() for p in text.split(',') if p.strip())


def _list(args) -> int:
    from advocc_ros.paths import config_dir
    from advocc_ros.model.scene import load_scene, read_yaml

    rows = []
    for path in sorted((config_dir() / 'scenes').glob('*.yaml')):
        scene = load_scene(path)
        raw = read_yaml(path)
        goal = scene.goal
        rows.append({'name': path.stem, 'objects': len(scene.objects),
                     'goal_center_m': list(goal.center.position_m) if goal else None,
                     'position_tolerance_m': list(goal.position_tolerance_m) if goal else None,
                     'orientation_tolerance_rad': (list(goal.orientation_tolerance_rad)
                                                   if goal else None),
                     'description': raw.get('description', ''), 'file': str(path)})
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f'{"scene":<18}{"objects":>8}  {"goal centre [m]":<22}description')
    for row in rows:
        centre = ('-' if row['goal_center_m'] is None
                  else ','.join(f'{v:.2f}' for v in row['goal_center_m']))
        print(f'{row["name"]:<18}{row["objects"]:>8}  {centre:<22}{row["description"]}')
    return 0


def _check(args) -> int:
    import numpy as np

    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.kinematics.ik import GoalSampler, start_configuration
    from advocc_ros.model.robot import load_robot

    if args.ik_attempts < 1:
        raise UserError('--ik-attempts must be >= 1')
    scene = scene_from_args(args)
    robot = load_robot(scene.robot)
    world = CollisionWorld(robot, scene.shapes)
    report = {'name': scene.name, 'objects': len(scene.objects), 'shapes': len(scene.shapes)}
    ok = True
    if scene.start is not None:
        q_init = start_configuration(scene, robot)
        report['start_valid'] = world.is_valid(q_init)
        report['start_clearance_m'] = world.scene_distance(q_init)
        ok &= report['start_valid']
    if scene.goal is not None:
        sampler = GoalSampler(robot, world.in_collision, scene.goal, np.random.default_rng(0))
        valid = sum(sampler.attempt() is not None for _ in range(args.ik_attempts))
        report.update(goal_center_m=list(scene.goal.center.position_m),
                      ik_attempts=sampler.attempts, ik_converged=sampler.converged,
                      ik_in_collision=sampler.colliding, ik_valid=valid)
        ok &= valid > 0
    if getattr(args, 'request', None):
        report.update(_request_validity(args.request, scene, robot, world))
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        for key, value in report.items():
            print(f'{key:>18}: {value}')
    return 0 if ok else 1


def _request_validity(path: str, scene, robot, world) -> dict:
    """Whether the request's own start and goal configurations are valid in our model (with the
    joints outside the planning group locked at the task's robot state)."""
    import numpy as np

    from advocc_ros.formats.mbm_scene import load_request

    request = load_request(path, robot)
    names = [o.id for o in scene.objects for _ in o.shapes]
    out = {'locked_joints': robot.locked_values}
    for key, state in (('start', request.start), ('goal', request.goal)):
        if state is None:
            out[f'request_{key}_valid'] = None  # no start state / a pose goal
            continue
        q = np.array([state[j] for j in robot.joint_names])
        out[f'request_{key}_valid'] = world.is_valid(q)
        if not out[f'request_{key}_valid']:
            out[f'request_{key}_within_limits'] = robot.within_limits(q)
            out[f'request_{key}_collisions'] = [list(p) for p in world.colliding_pairs(q, names)]
    return out


def _convert(args) -> int:
    from advocc_ros.model.scene import save_yaml_atomic

    scene = scene_from_args(args)
    data = scene.to_data()
    data['description'] = f'converted from {args.scene}' + (
        f' and {args.request}' if args.request else '')
    save_yaml_atomic(args.out, data)
    print(args.out)
    return 0


def _vary(args) -> int:
    from advocc_ros.scenes.variations import VariationConfig, write_variation

    if args.count < 1:
        raise UserError('--count must be >= 1')
    try:
        config = VariationConfig(jitter_pos_m=args.jitter_pos, jitter_size=args.jitter_size,
                                 jitter_yaw_rad=args.jitter_yaw, fixed=_patterns(args.fixed),
                                 rigid=_patterns(args.rigid), target=_patterns(args.target))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    scene = scene_from_args(args)
    if scene.start is None:
        raise UserError(f'{args.scene}: the scene needs a start configuration to be varied')
    out = pathlib.Path(args.out)
    rows = []
    for index in range(args.count):
        path, var = write_variation(scene, index, args.seed, out, config)
        rows.append({'file': str(path), 'index': index, 'draws': var.draws,
                     'redrawn_objects': var.redrawn_objects})
        if not args.json:
            print(f'{path}  (draws {var.draws}, objects re-drawn {var.redrawn_objects})')
            sys.stdout.flush()
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0


def _sense(args) -> int:
    from advocc_ros.scenes.sensing import SensingConfig, write_sensed_scene

    if not (args.spacing > 0 and args.noise >= 0):
        raise UserError('--spacing must be > 0 and --noise >= 0')
    cfg = SensingConfig(spacing_m=args.spacing, noise_m=args.noise,
                        resolution_m=args.resolution, seed=args.seed)
    print(write_sensed_scene(scene_from_args(args), args.out, cfg))
    return 0
