"""``advocc heatmap build|info|merge|plot``: the offline phase from the command line."""

from __future__ import annotations

import argparse
import json
import sys

from advocc_ros.cli import UserError
from advocc_ros.heatmap import (HeatmapConfig, build_heatmap, load_heatmap, merge_heatmaps,
                                save_heatmap)
from advocc_ros.commands.common import add_scene_args, scene_from_args


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('heatmap', help='build, inspect, merge and plot heatmaps')
    hsub = parser.add_subparsers(dest='heatmap_command', required=True)

    build = hsub.add_parser('build', help='sample valid configurations and accumulate H')
    add_scene_args(build)
    build.add_argument('--samples', type=int, default=HeatmapConfig.samples,
                       help='valid configurations N_off (default %(default)s)')
    build.add_argument('--out', required=True, help='output .npz file')
    build.add_argument('--voxel', type=float, default=HeatmapConfig.voxel_m,
                       help='voxel edge delta [m] (default %(default)s)')
    build.add_argument('--seed', type=int, default=0)
    build.add_argument('--workers', type=int, default=1, help='worker processes')
    build.add_argument('--shard', default='0/1', metavar='I/K',
                       help='build shard I of K of the seed\'s samples (merge the K shards)')
    build.add_argument('--robot-only', action='store_true',
                       help='ignore the scene offline; attacks mask the current scene instead')
    build.add_argument('--json', action='store_true', help='print a JSON summary')
    build.set_defaults(func=_build)

    info = hsub.add_parser('info', help='print what a heatmap file holds')
    info.add_argument('file')
    info.add_argument('--json', action='store_true')
    info.set_defaults(func=_info)

    merge = hsub.add_parser('merge', help='sum shards built with different seeds')
    merge.add_argument('out')
    merge.add_argument('inputs', nargs='+')
    merge.add_argument('--json', action='store_true')
    merge.set_defaults(func=_merge)

    plot = hsub.add_parser('plot', help='slices through the peak (paper Fig. 4)')
    plot.add_argument('file')
    plot.add_argument('--out', required=True, help='PNG file')
    add_scene_args(plot, required=False)  # the scene's start/goal and corridor are drawn
    plot.add_argument('--obstacles', help='obstacles YAML: draw the placed boxes')
    plot.add_argument('--at', help='slice through x,y,z [m] instead of the peak')
    plot.set_defaults(func=_plot)


def _print_summary(summary: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(summary, indent=2))
        return
    for key, value in summary.items():
        print(f'{key:>16}: {value}')


def _build(args) -> int:
    if args.samples < 1:
        raise UserError(f'--samples must be >= 1, got {args.samples}')
    if args.workers < 1:
        raise UserError(f'--workers must be >= 1, got {args.workers}')
    try:
        shard = tuple(int(v) for v in args.shard.split('/'))
        assert len(shard) == 2 and 0 <= shard[0] < shard[1]
    except (ValueError, AssertionError):
        raise UserError(f'--shard: expected I/K with 0 <= I < K, got {args.shard!r}') from None
    scene = scene_from_args(args)
    cfg = HeatmapConfig(samples=args.samples, voxel_m=args.voxel, robot_only=args.robot_only)
    from advocc_ros.progress import progress_bar
    with progress_bar(args.samples, 'heatmap', 'q', file=sys.stderr, leave=False) as bar:
        heatmap = build_heatmap(scene, cfg, seed=args.seed, workers=args.workers,
                                progress=bar.update, shard=shard)
    return _save_and_report(heatmap, args)


def _save_and_report(heatmap, args) -> int:
    save_heatmap(heatmap, args.out)
    summary = heatmap.summary()
    summary['file'] = str(args.out)
    _print_summary(summary, args.json)
    return 0


def _info(args) -> int:
    _print_summary(load_heatmap(args.file).summary(), args.json)
    return 0


def _merge(args) -> int:
    return _save_and_report(merge_heatmaps([load_heatmap(p) for p in args.inputs]), args)


def _plot(args) -> int:
    from advocc_ros.evaluation.figures import plot_heatmap_slices

    at = None
    if args.at:
        try:
            at = [float(v) for v in args.at.split(',')]
        except ValueError:
            raise UserError(f'--at: expected x,y,z in metres, got {args.at!r}') from None
        if len(at) != 3:
            raise UserError(f'--at: expected 3 numbers, got {args.at!r}')
    scene = scene_from_args(args)
    obstacles = None
    if args.obstacles:
        from advocc_ros.model.scene import objects_from_data, read_yaml
        data = read_yaml(args.obstacles)
        if not isinstance(data, dict):
            raise UserError(f'{args.obstacles}: expected a mapping with objects')
        obstacles = objects_from_data(data.get('objects'), f'{args.obstacles}.objects')
    plot_heatmap_slices(load_heatmap(args.file), args.out, scene=scene, obstacles=obstacles,
                        at_m=at)
    print(args.out)
    return 0
