"""``advocc demo``: the main job end to end on the default scene (what `make demo` runs).

1. offline: build (or reuse) the kinematic occupancy heatmap and plot its slices;
2. online: attack through the ROS graph (heatmap_server + attacker processes);
3. evaluation: the three OMPL planners without and with the attack, as a Table I excerpt.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

from advocc_ros.heatmap import HeatmapConfig, build_heatmap, load_heatmap, save_heatmap
from advocc_ros.commands.common import add_scene_args, scene_from_args


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('demo', help='heatmap, attack and evaluation on the default scene')
    add_scene_args(parser, required=False)
    parser.set_defaults(scene='table_pick')
    parser.add_argument('--out', default='out/demo', help='output folder')
    parser.add_argument('--samples', type=int, default=HeatmapConfig.samples)
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--rebuild', action='store_true', help='rebuild an existing heatmap')
    parser.add_argument('--budget', type=int, default=3, help='boxes for the attack stage')
    parser.add_argument('--trials', type=int, default=10, help='plans per planner and attack')
    parser.add_argument('--time', type=float, default=5.0, help='planning budget [s]')
    parser.add_argument('--planners', default='rrtconnect,prmstar,bkpiece1')
    parser.set_defaults(func=run)


def _stage(title: str) -> None:
    print(f'\n== {title}', flush=True)


def run(args) -> int:
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = scene_from_args(args)

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
    from advocc_ros.figures import plot_heatmap_slices
    plot_heatmap_slices(heatmap, out / f'heatmap_{scene.name}.png', scene=scene)
    print(f'slice figure: {out / f"heatmap_{scene.name}.png"}')

    _stage(f'2. online: attack with M={args.budget} through heatmap_server + attacker nodes')
    from advocc_ros.attack import load_obstacles
    from advocc_ros.attack_demo import run_attack_nodes
    obstacles_file = out / f'obstacles_{scene.name}_ours_{args.budget}.yaml'
    reply = run_attack_nodes(heatmap_file, scene, obstacles_file, budget=args.budget)
    obstacles, _ = load_obstacles(obstacles_file)
    for obj in obstacles:
        center = [round(v, 3) for v in obj.shapes[0].pose.position_m]
        print(f'  {obj.id}: centre {center} m, edge {obj.shapes[0].dims[0]} m')
    print(f'obstacles file: {obstacles_file} (boxes arrived {reply["seconds_to_boxes"]} s '
          'after the scene was published, node start-up included)')
    plot_heatmap_slices(heatmap, out / f'attack_{scene.name}.png', scene=scene,
                        obstacles=obstacles)

    _stage(f'3. evaluation: {args.trials} plans per planner, {args.time:g} s budget, '
           'without and with the attack')
    from advocc_ros.metrics import evaluate_planner, format_value
    rows = []
    for planner_id in [p for p in args.planners.split(',') if p]:
        for label, attacked in (('none', scene),
                                (f'ours M={args.budget}', scene.with_objects(obstacles))):
            row = evaluate_planner(attacked, planner_id, args.trials, args.time, seed=0,
                                   workers=args.workers)
            rows.append((planner_id, label, row))
            print(f'  {planner_id:<10} {label:<10} PSR {format_value(row["psr"], 2)}',
                  flush=True)
    table = _table(scene.name, rows)
    (out / 'table.md').write_text(table)
    print()
    print(table)
    return 0


def _table(scene_name: str, rows: list) -> str:
    """Markdown table with the paper's Table I columns (SMR and CMR x10^-2)."""
    from advocc_ros.metrics import format_value
    lines = [f'Scene {scene_name}', '',
             '| planner | attack | trials | PSR | SMR | CMR | JDS | PT [s] |',
             '|---|---|---|---|---|---|---|---|']
    for planner_id, label, row in rows:
        lines.append(f'| {planner_id} | {label} | {row["trials"]} | '
                     f'{format_value(row["psr"], 2)} | {format_value(row["smr"])} | '
                     f'{format_value(row["cmr"])} | {format_value(row["jds"])} | '
                     f'{format_value(row["pt"])} |')
    return '\n'.join(lines) + '\n'
