"""``advocc perf ...``: benchmarks that report measured numbers (never timed unit tests)."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.commands.common import add_scene_args, scene_from_args
from advocc_ros.evaluation.perf import machine


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('perf', help='benchmarks')
    psub = parser.add_subparsers(dest='perf_command', required=True)
    heat = psub.add_parser('heatmap', help='time the offline heatmap build')
    add_scene_args(heat, required=False)
    heat.set_defaults(scene='table_pick')
    heat.add_argument('--samples', type=int, default=HeatmapConfig.samples)
    heat.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    heat.add_argument('--repeats', type=int, default=3)
    heat.add_argument('--json', action='store_true')
    heat.set_defaults(func=_heatmap)
    plan = psub.add_parser('planning', help='validity checks/s, planning time and PSR per '
                           'planner, worker overhead')
    add_scene_args(plan, required=False)
    plan.set_defaults(scene='table_pick')
    plan.add_argument('--planners', default='rrtconnect,prmstar,bkpiece1')
    plan.add_argument('--trials', type=int, default=20)
    plan.add_argument('--time', type=float, default=5.0, help='planning budget [s]')
    plan.add_argument('--json', action='store_true')
    plan.set_defaults(func=_planning)
    speed = psub.add_parser('speed', help='this machine\'s speed as a data set\'s records '
                            'name it (validity checks/s), to tell before a build or a resume '
                            'whether its PSRs will pool with the folder\'s')
    speed.add_argument('--json', action='store_true')
    speed.set_defaults(func=_speed)
    from advocc_ros.commands.perf_attack import register_attack
    from advocc_ros.commands.perf_bench import register_bench
    from advocc_ros.commands.perf_load import register_load
    register_attack(psub)
    register_bench(psub)
    register_load(psub)


def _heatmap(args) -> int:
    scene = scene_from_args(args)
    cfg = HeatmapConfig(samples=args.samples)
    # First build includes one-time costs (the kernels' library loaded, link tables).
    t0 = time.perf_counter()
    build_heatmap(scene, HeatmapConfig(samples=200), seed=12345)
    warmup_s = time.perf_counter() - t0
    walls, candidates = [], 0
    for rep in range(max(args.repeats, 1)):
        t0 = time.perf_counter()
        heatmap = build_heatmap(scene, cfg, seed=rep, workers=args.workers)
        walls.append(time.perf_counter() - t0)
        candidates = heatmap.meta['candidates']
    med = statistics.median(walls)
    report = {
        'benchmark': 'heatmap build', 'scene': scene.name, 'objects': len(scene.objects),
        'valid_samples': args.samples, 'candidates_per_build': candidates,
        'voxel_m': cfg.voxel_m, 'grid_shape': list(heatmap.grid.shape),
        'workers': args.workers, 'repeats': len(walls),
        'wall_s': [round(w, 3) for w in walls], 'median_wall_s': round(med, 3),
        'valid_samples_per_s': round(args.samples / med, 1),
        'warmup_s': round(warmup_s, 3), 'paper_offline_s': 1251.47,
        'speedup_vs_paper': round(1251.47 / med, 1), 'machine': machine(),
    }
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for key, value in report.items():
            print(f'{key:>22}: {value}')
    return 0


def _speed(args) -> int:
    from advocc_ros.evaluation.provenance import SPEED_SCENE, SPEED_SPREAD, now, speed, stamp

    report = {'speed_checks_per_s': speed(), 'scene': SPEED_SCENE, 'pools_within': SPEED_SPREAD,
              'machine': machine(), 'made': dict(stamp(), at=now())}
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f'{report["speed_checks_per_s"]:,.0f} validity checks/s ({SPEED_SCENE}, the '
              f'default Panda): records within {SPEED_SPREAD:g}x of it pool')
    return 0


def _planning(args) -> int:
    from advocc_ros.evaluation.perf import benchmark_planning

    report = benchmark_planning(scene_from_args(args),
                                tuple(p for p in args.planners.split(',') if p),
                                trials=args.trials, time_budget_s=args.time)
    report['machine'] = machine()
    print(json.dumps(report, indent=2) if args.json else report)
    return 0
