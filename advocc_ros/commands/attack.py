"""``advocc attack``: place adversarial boxes for a scene's task from a heatmap file.

Where a planner is used: never by ``task``, ``ours`` or ``random`` themselves. The task's witness
(needed by ``--policy solvable``, and by ``--certify`` for a verdict that can say ``certified``)
is found first, once per task, by one RRTConnect run on the unattacked scene
(``advocc_ros.attack.edges``; reported apart as ``witness_search_ms``). PFA and PFA++ query
planners by design (``--workers`` local processes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from advocc_ros.attack import (AttackConfig, AttackStatus, load_method, obstacles_data,
                               save_obstacles)
from advocc_ros.attack.edges import attack_task
from advocc_ros.cli import UserError
from advocc_ros.commands.common import (add_attack_args, add_bag_arg, add_scene_args,
                                        add_task_option_arg, check_bag_arg, refuse_invalid_task,
                                        scene_from_args, task_options_from_args)
from advocc_ros.heatmap import HeatmapError, load_heatmap
from advocc_ros.model.robot import RobotError, load_robot
from advocc_ros.model.pose import SceneError
from advocc_ros.planning.witness import save_witness, witness_file


def register(sub: argparse._SubParsersAction) -> None:
    defaults = AttackConfig()
    p = sub.add_parser('attack', help='place adversarial boxes (Task, the paper\'s Algorithm 1, '
                       'Random, PFA, PFA++)')
    p.add_argument('--heatmap', required=True, help='heatmap .npz file')
    add_scene_args(p)
    p.add_argument('--budget', type=int, required=True, help='M, number of boxes')
    add_attack_args(p)
    add_task_option_arg(p)
    p.add_argument('--certify', action='store_true',
                   help='under --policy paper/reachable: also find the task\'s witness (one '
                   'RRTConnect run on the unattacked scene, cached per task) so the verdict can '
                   'say certified; without it no planner is started and the verdict is goal '
                   'blocked or unknown (--policy solvable always finds the witness)')
    p.add_argument('--reachable-fraction', type=float, default=defaults.reachable_fraction,
                   help='under --policy reachable (default %(default)s)')
    p.add_argument('--corridor', type=float, default=defaults.corridor_radius_m,
                   help='corridor radius r_corr [m] (default %(default)s)')
    p.add_argument('--d-safe', type=float, default=defaults.d_safe_m,
                   help='clearance from the robot at start and the goal [m] (default '
                   '%(default)s)')
    p.add_argument('--d-min', type=float, default=defaults.d_min_m,
                   help='minimum distance between box centres [m] (default %(default)s)')
    p.add_argument('--victim-margin', type=float, default=defaults.victim_margin_m,
                   help='distance the boxes keep from the witness and a joint goal beyond the '
                   'certificate\'s guard margin, room for the victims\' own collision models; '
                   'the kept witness is chosen for this clearance from the scene too [m] '
                   '(default %(default)s)')
    g = p.add_argument_group('planner in the loop (pfa, pfa++)')
    g.add_argument('--planner', help='victim planner pfa++ queries: rrtconnect, prmstar, '
                   'bkpiece1 (default rrtconnect); pfa always queries rrtconnect')
    g.add_argument('--queries', type=int, default=150,
                   help='Q, planner queries in total, baseline included (default %(default)s)')
    g.add_argument('--queries-per-placement', type=int, default=3, metavar='K',
                   help='planner queries per scored placement (default %(default)s)')
    g.add_argument('--query-time', type=float, default=1.0,
                   help='time budget of one query [s] (default %(default)s)')
    g.add_argument('--workers', type=int, default=1,
                   help='local planner processes queried in parallel (default %(default)s)')
    g.add_argument('--no-progress', action='store_true', help='no progress bar on stderr')
    p.add_argument('--out', required=True, help='obstacles YAML to write')
    add_bag_arg(p)
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    p.set_defaults(func=_attack)


def _attack(args: argparse.Namespace) -> int:
    check_bag_arg(args)
    options = task_options_from_args(args, args.method)
    if not load_method(args.method):
        raise UserError(f'method {args.method!r} is not available in this installation')
    try:
        cfg = AttackConfig(box_size_m=args.size, corridor_radius_m=args.corridor,
                           d_safe_m=args.d_safe, d_min_m=args.d_min, goal_policy=args.policy,
                           reachable_fraction=args.reachable_fraction,
                           victim_margin_m=args.victim_margin, search_witness=args.certify)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    scene, robot, heatmap, q_init = _load_task(args)
    refuse_invalid_task(scene, args.scene)  # before any planner (PFA's, the witness search)
    if heatmap.meta.get('scene_hash') not in (None, scene.objects_hash()):
        print(f'advocc attack: warning: {args.heatmap} was built for scene '
              f'{heatmap.meta.get("scene_name")!r}, not {scene.name!r}; the current scene is '
              'masked, but its heatmap mass may be off', file=sys.stderr)
    extra = {'heatmap_file': str(args.heatmap), 'seed': args.seed}
    if args.method == 'task':  # what the attack ran with; `advocc export` attacks alike
        from advocc_ros.attack.task import TaskOptions
        extra['task_options'] = dataclasses.asdict(options or TaskOptions())
    if args.method in ('pfa', 'pfa++'):
        result = _attack_in_the_loop(args, heatmap, robot, scene, q_init, cfg)
        extra['pfa'] = result.stats.get(args.method, {})
    else:
        result = attack_task(heatmap, robot, scene.objects, q_init, scene.goal, args.budget,
                             args.method, cfg, seed=args.seed, method_options=options)
    if not result.status.ok:
        raise UserError(f'{result.status.value}: {result.message}')
    data = obstacles_data(result, heatmap, scene.name, scene.objects_hash(), extra)
    save_obstacles(args.out, data)
    witness_out = None
    if result.solvable is not None and result.solvable.certified:
        witness_out = witness_file(args.out)
        save_witness(witness_out, result.witness)
    if args.bag:
        from advocc_ros.ros.bag import write_attack_bag
        write_attack_bag(args.bag, scene, result.obstacles, heatmap)
    if args.json:
        print(json.dumps(dict(result.to_json(), out=str(args.out),
                              witness_file=str(witness_out) if witness_out else None), indent=2))
    else:
        _print_attack(args, result, witness_out)
    if result.status == AttackStatus.PARTIAL:
        print(f'advocc attack: warning: {result.message}', file=sys.stderr)
    return 0


def _load_task(args: argparse.Namespace):
    """The scene, robot, heatmap and start configuration the arguments name; ``UserError``
    with the reason when one cannot be loaded or the scene has no start or goal."""
    try:
        scene = scene_from_args(args)
        if scene.start is None or scene.goal is None:
            raise UserError(f'{args.scene}: the scene needs a start and a goal to attack')
        robot = load_robot(scene.robot)
        heatmap = load_heatmap(args.heatmap, robot_hash=robot.hash)
        q_init = robot.q_from_names(list(scene.start), list(scene.start.values()),
                                    f'{args.scene}.start')
    except (SceneError, HeatmapError, RobotError) as exc:
        raise UserError(str(exc)) from None
    return scene, robot, heatmap, q_init


def _print_attack(args: argparse.Namespace, result, witness_out) -> None:
    """The attack's boxes, masses, goal poses left valid, witness search and verdict, as text."""
    print(f'{result.status.value}: {result.message} ({args.method}, '
          f'{result.compute_s * 1e3:.1f} ms) -> {args.out}')
    for obj, mass in zip(result.obstacles, result.masses):
        x, y, z = obj.shapes[0].pose.position_m
        print(f'  {obj.id:8s} centre [{x:+.3f}, {y:+.3f}, {z:+.3f}] m  mass {mass:.3f}')
    print(f'  total mass {result.total_mass:.3f}')
    if result.goal_valid_fraction is not None:
        print(f'  goal poses still valid: {100 * result.goal_valid_fraction:.0f} % of '
              f'{result.stats["goal_samples"]} fixed goal samples (policy '
              f'{result.goal_policy})')
    if 'witness_search_ms' in result.stats:
        print(f'  witness search (RRTConnect on the unattacked scene, cached per task, '
              f'not attack time): {result.stats["witness_search_ms"]:.0f} ms')
    if result.solvable is not None:
        print(f'  solvable: {result.solvable.verdict} ({result.solvable.message})'
              + (f'; witness -> {witness_out}' if witness_out else ''))


def _attack_in_the_loop(args: argparse.Namespace, heatmap, robot, scene, q_init,
                        cfg: AttackConfig):
    """PFA / PFA++ with ``--workers`` local planner processes and a progress bar."""
    from advocc_ros.attack.pfa import PFA_PLANNER, PfaConfig, PfaOptions
    from advocc_ros.planning.pool import LocalPlanners

    if args.method == 'pfa' and args.planner not in (None, PFA_PLANNER):
        raise UserError(f'pfa always queries {PFA_PLANNER} with the exact goal pose; use '
                        f'--method pfa++ to query {args.planner} with the goal region')
    if args.workers < 1:
        raise UserError(f'--workers must be >= 1, got {args.workers}')
    try:
        pcfg = PfaConfig(queries=args.queries, queries_per_placement=args.queries_per_placement,
                         query_time_s=args.query_time, planner_id=args.planner or PFA_PLANNER)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    bar = None

    def progress(done: int, total: int) -> None:
        bar.update(done - bar.n)

    try:
        with LocalPlanners(scene, args.workers) as planners:
            planners.start()  # process start-up is not part of the attack's online time
            if not args.no_progress:
                from advocc_ros.progress import progress_bar
                victim = pcfg.planner_id if args.method == 'pfa++' else PFA_PLANNER
                bar = progress_bar(pcfg.queries, f'{args.method} ({victim})', 'query',
                                   file=sys.stderr)
            return attack_task(heatmap, robot, scene.objects, q_init, scene.goal, args.budget,
                               args.method, cfg, seed=args.seed,
                               method_options=PfaOptions(
                                   planners, pcfg, progress if bar is not None else None))
    finally:
        if bar is not None:
            bar.close()
