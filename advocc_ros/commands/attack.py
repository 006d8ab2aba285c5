"""``advocc attack``: place adversarial boxes for a scene's task from a heatmap file."""

from __future__ import annotations

import argparse
import json
import sys

from advocc_ros.attack import (KNOWN_METHODS, AttackConfig, AttackStatus, attack, load_method,
                               obstacles_data, save_obstacles)
from advocc_ros.cli import UserError
from advocc_ros.heatmap import HeatmapError, load_heatmap
from advocc_ros.paths import scene_path
from advocc_ros.robot import RobotError, load_robot
from advocc_ros.scene import SceneError, load_scene


def register(sub: argparse._SubParsersAction) -> None:
    defaults = AttackConfig()
    p = sub.add_parser('attack', help='place adversarial boxes (paper Algorithm 1 or Random)')
    p.add_argument('--heatmap', required=True, help='heatmap .npz file')
    p.add_argument('--scene', required=True, help='scene YAML (or a name in config/scenes) '
                   'with start and goal')
    p.add_argument('--budget', type=int, required=True, help='M, number of boxes')
    # pfa / pfa++ are planner-in-the-loop baselines provided by advocc_ros.pfa when present.
    p.add_argument('--method', default='ours', choices=KNOWN_METHODS)
    p.add_argument('--size', type=float, default=defaults.box_size_m,
                   help='box edge s [m] (default %(default)s)')
    p.add_argument('--corridor', type=float, default=defaults.corridor_radius_m,
                   help='corridor radius r_corr [m] (default %(default)s)')
    p.add_argument('--d-safe', type=float, default=defaults.d_safe_m,
                   help='clearance from the robot at start and the goal [m] (default '
                   '%(default)s)')
    p.add_argument('--d-min', type=float, default=defaults.d_min_m,
                   help='minimum distance between box centres [m] (default %(default)s)')
    p.add_argument('--seed', type=int, default=0, help='random generator seed (random method)')
    p.add_argument('--out', required=True, help='obstacles YAML to write')
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    p.set_defaults(func=_attack)


def _attack(args: argparse.Namespace) -> int:
    if not load_method(args.method):
        raise UserError(f'method {args.method!r} is not available in this installation')
    try:
        cfg = AttackConfig(box_size_m=args.size, corridor_radius_m=args.corridor,
                           d_safe_m=args.d_safe, d_min_m=args.d_min)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    try:
        scene = load_scene(scene_path(args.scene))
        if scene.start is None or scene.goal is None:
            raise UserError(f'{args.scene}: the scene needs a start and a goal to attack')
        robot = load_robot(scene.robot)
        heatmap = load_heatmap(args.heatmap, robot_hash=robot.hash)
        q_init = robot.q_from_names(list(scene.start), list(scene.start.values()),
                                    f'{args.scene}.start')
    except (SceneError, HeatmapError, RobotError) as exc:
        raise UserError(str(exc)) from None
    if heatmap.meta.get('scene_hash') not in (None, scene.objects_hash()):
        print(f'advocc attack: warning: {args.heatmap} was built for scene '
              f'{heatmap.meta.get("scene_name")!r}, not {scene.name!r}; the current scene is '
              'masked, but its heatmap mass may be off', file=sys.stderr)
    result = attack(heatmap, robot, scene.objects, q_init, scene.goal, args.budget,
                    args.method, cfg, seed=args.seed)
    if not result.status.ok:
        raise UserError(f'{result.status.value}: {result.message}')
    data = obstacles_data(result, heatmap, scene.name, scene.objects_hash(),
                          {'heatmap_file': str(args.heatmap), 'seed': args.seed})
    save_obstacles(args.out, data)
    if args.json:
        print(json.dumps(dict(result.to_json(), out=str(args.out)), indent=2))
    else:
        print(f'{result.status.value}: {result.message} ({args.method}, '
              f'{result.compute_s * 1e3:.1f} ms) -> {args.out}')
        for obj, mass in zip(result.obstacles, result.masses):
            x, y, z = obj.shapes[0].pose.position_m
            print(f'  {obj.id:8s} centre [{x:+.3f}, {y:+.3f}, {z:+.3f}] m  mass {mass:.3f}')
        print(f'  total mass {result.total_mass:.3f}')
    if result.status == AttackStatus.PARTIAL:
        print(f'advocc attack: warning: {result.message}', file=sys.stderr)
    return 0
