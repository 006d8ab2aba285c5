"""``advocc demo``: the main job end to end on the default scene (what `make demo` runs).

1. offline: build (or reuse) the kinematic occupancy heatmap and plot its slices;
2. MAIN: the audit (``advocc audit --policy solvable``): how few boxes make the pick
   impossible (goal blocked, a paper-policy task attack), and how few make RRTConnect, PRM* and
   BKPIECE1 fail while it stays certified solvable (a solvable-policy task attack, its
   prefixes evaluated);
3. online: the task attack through the ROS graph (heatmap_server + attacker processes),
   recorded as a ROS 2 bag;
4. benchmark: the orchestrator runs a short version of the paper's protocol on the scene
   (heatmap_server + planner shims as processes; task, ours and random, budgets 1 and 3, the
   three OMPL planners, an unattacked baseline, 3 trials per cell) under the ``solvable`` goal
   policy (a failure counts only while the task stays certified) and prints Table I.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

from advocc_ros.heatmap import HeatmapConfig, build_heatmap, load_heatmap, save_heatmap
from advocc_ros.commands.common import add_scene_args, scene_from_args


def register(sub: argparse._SubParsersAction) -> None:
    from advocc_ros.attack.types import POLICIES

    parser = sub.add_parser('demo', help='heatmap, attack and evaluation on the default scene')
    add_scene_args(parser, required=False)
    parser.set_defaults(scene='table_pick')
    parser.add_argument('--out', default='out/demo', help='output folder')
    parser.add_argument('--samples', type=int, default=HeatmapConfig.samples)
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--rebuild', action='store_true', help='rebuild an existing heatmap')
    parser.add_argument('--audit-budget', type=int, default=5,
                        help='audit: boxes of the attack whose prefixes are evaluated')
    parser.add_argument('--audit-trials', type=int, default=6,
                        help='audit: trials per planner and budget')
    parser.add_argument('--audit-time', type=float, default=5.0,
                        help='audit: planning budget [s] (the paper\'s 5)')
    parser.add_argument('--audit-policy', default='solvable', choices=POLICIES,
                        help='audit: goal policy of the evaluated attack (default %(default)s; '
                             'the goal-blocked answer comes from a paper one either way)')
    parser.add_argument('--bench-policy', default='solvable', choices=POLICIES,
                        help='benchmark: goal policy of the attacks (default %(default)s: a '
                             'planner failure counts only while the task stays certified '
                             'solvable; paper cells whose goal is blocked show it in '
                             'hardness.md)')
    parser.add_argument('--budget', type=int, default=3, help='boxes for the attack stage')
    parser.add_argument('--trials', type=int, default=3, help='benchmark: trials per table cell')
    parser.add_argument('--time', type=float, default=2.0,
                        help='benchmark: planning budget [s] (the paper: 5)')
    parser.add_argument('--shims', type=int, default=2, help='planner_shim processes')
    parser.add_argument('--planners', default='rrtconnect,prmstar,bkpiece1')
    parser.set_defaults(func=run)


def _stage(title: str) -> None:
    print(f'\n== {title}', flush=True)


def run(args) -> int:
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = scene_from_args(args)
    heatmap, heatmap_file = _heatmap_stage(args, scene, out)
    planners = tuple(p for p in args.planners.split(',') if p)
    audit = _audit_stage(args, scene, heatmap, planners, out)
    _attack_stage(args, scene, heatmap, heatmap_file, out)
    summary = _bench_stage(args, planners, heatmap_file, out)
    from advocc_ros.audit.report import audit_answer
    _stage(f'the answer (stage 2; report in {out / "audit" / "audit.md"})')
    print(audit_answer(audit))
    return 0 if summary['missing'] == 0 else 1


def _heatmap_stage(args, scene, out: pathlib.Path):
    """Stage 1: build the heatmap (or reuse the one in ``out``) and plot its slices; the
    heatmap and its file."""
    _stage(f'1. offline: kinematic occupancy heatmap for {scene.name} ({args.samples} samples)')
    heatmap_file = out / f'heatmap_{scene.name}.npz'
    if heatmap_file.exists() and not args.rebuild:
        heatmap = load_heatmap(heatmap_file)
        print(f'reusing {heatmap_file} (built in {heatmap.meta["build_s"]} s; --rebuild to redo)')
    else:
        t0 = time.perf_counter()
        heatmap = build_heatmap(scene, HeatmapConfig(samples=args.samples), seed=0,
                                workers=args.workers)
        save_heatmap(heatmap, heatmap_file)
        print(f'built {heatmap_file} in {time.perf_counter() - t0:.2f} s')
    summary = heatmap.summary()
    print(json.dumps({k: summary[k] for k in ('valid_samples', 'candidates', 'build_s',
                                              'shape', 'nonzero_voxels', 'total_mass')}))
    from advocc_ros.evaluation.figures import plot_heatmap_slices
    plot_heatmap_slices(heatmap, out / f'heatmap_{scene.name}.png', scene=scene)
    print(f'slice figure: {out / f"heatmap_{scene.name}.png"}')
    return heatmap, heatmap_file


def _audit_stage(args, scene, heatmap, planners: tuple[str, ...], out: pathlib.Path) -> dict:
    """Stage 2, the main job: the audit of the task attack's prefixes; the audit."""
    _stage(f'2. MAIN: audit - how few boxes make the pick impossible, and how few make '
           f'{", ".join(planners)} fail while it stays solvable? (task attack, goal policy '
           f'{args.audit_policy}, up to {args.audit_budget} boxes, {args.audit_trials} trials x '
           f'{args.audit_time:g} s)')
    from advocc_ros.commands.audit import run_audit_to
    from advocc_ros.audit.audit import AuditConfig
    from advocc_ros.audit.report import audit_answer, budget_table
    audit_cfg = AuditConfig(planners=planners, max_budget=args.audit_budget,
                            trials=args.audit_trials, time_budget_s=args.audit_time,
                            method='task', policy=args.audit_policy,
                            workers=max(1, min(2, args.workers)))
    audit = run_audit_to(scene, heatmap, audit_cfg, out / 'audit')
    print()
    print(audit_answer(audit))
    print()
    print(budget_table(audit))
    return audit


def _attack_stage(args, scene, heatmap, heatmap_file: pathlib.Path, out: pathlib.Path) -> None:
    """Stage 3: the task attack through heatmap_server and attacker, written as an obstacles
    file and a ROS 2 bag, and drawn on the heatmap's slices."""
    _stage(f'3. online: task attack with M={args.budget} through heatmap_server + attacker '
           'nodes')
    from advocc_ros.attack import load_obstacles
    from advocc_ros.evaluation.figures import plot_heatmap_slices
    from advocc_ros.ros.feeder import run_attack_nodes
    obstacles_file = out / f'obstacles_{scene.name}_task_{args.budget}.yaml'
    bag_file = obstacles_file.with_suffix('.mcap')
    reply = run_attack_nodes(heatmap_file, scene, obstacles_file, budget=args.budget,
                             method='task', bag=bag_file)
    obstacles, _ = load_obstacles(obstacles_file)
    for obj in obstacles:
        center = [round(v, 3) for v in obj.shapes[0].pose.position_m]
        print(f'  {obj.id}: centre {center} m, edge {obj.shapes[0].dims[0]} m')
    print(f'obstacles file: {obstacles_file} (boxes arrived {reply["seconds_to_boxes"]} s '
          'after the scene was published, node start-up included)')
    print(f'ROS 2 bag of the attack: {bag_file} (ros2 bag play, or Foxglove)')
    plot_heatmap_slices(heatmap, out / f'attack_{scene.name}.png', scene=scene,
                        obstacles=obstacles)


def _bench_stage(args, planners: tuple[str, ...], heatmap_file: pathlib.Path,
                 out: pathlib.Path) -> dict:
    """Stage 4: a short benchmark through the orchestrator and the nodes, Table I printed; the
    run's summary."""
    _stage(f'4. benchmark through the nodes: orchestrator, {args.shims} planner shims, '
           f'{args.trials} trials per cell, {args.time:g} s budget, goal policy '
           f'{args.bench_policy}')
    from advocc_ros.bench import load_profile
    from advocc_ros.orchestrator import Orchestrator
    from advocc_ros.paths import config_dir
    data = load_profile(config_dir() / 'bench.yaml', 'quick').to_data()
    data.update(scenes=[args.scene], planners=list(planners),
                methods=['task', 'ours', 'random'], budgets=[1, 3], trials=args.trials,
                time_budget_s=args.time, shims=args.shims, goal_policy=args.bench_policy)
    from advocc_ros.bench import BenchConfig
    cfg = BenchConfig.from_data(data, 'advocc demo')
    run_dir = out / 'bench'
    summary = Orchestrator(cfg, run_dir, {'*': [str(heatmap_file.resolve())]}).run()
    print(f'{summary["done"]}/{summary["planned"]} trials ({summary["status"]}, '
          f'{summary["wall_s"]:.0f} s); tables and figures in {run_dir}')
    for note in summary['notes']:
        print(f'note: {note}')
    if summary['internal_errors']:
        print(f'warning: {summary["internal_errors"]} trials were internal errors (left out of '
              f'PSR){": " + summary["reason"] if summary["reason"] else ""}', file=sys.stderr)
    print()
    print((run_dir / 'table1.md').read_text())
    if args.bench_policy != 'solvable':  # PSR 0 on a goal-blocked task is no planner failure
        print(f'goal policy {args.bench_policy}: the attacks\' verdicts (certified / goal '
              f'blocked / unknown) per cell are in {run_dir / "hardness.md"}')
    return summary
