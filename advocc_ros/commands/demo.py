"""``advocc demo``: the main job end to end on the default scene (what `make demo` runs)."""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

from advocc_ros.heatmap import HeatmapConfig, build_heatmap, load_heatmap, save_heatmap
from advocc_ros.paths import scene_path
from advocc_ros.scene import load_scene


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('demo', help='heatmap, attack and evaluation on the default scene')
    parser.add_argument('--scene', default='table_pick')
    parser.add_argument('--out', default='out/demo', help='output folder')
    parser.add_argument('--samples', type=int, default=HeatmapConfig.samples)
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--rebuild', action='store_true', help='rebuild an existing heatmap')
    parser.set_defaults(func=run)


def _stage(title: str) -> None:
    print(f'\n== {title}', flush=True)


def run(args) -> int:
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene_file = scene_path(args.scene)
    scene = load_scene(scene_file)

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
    figure = out / f'heatmap_{scene.name}.png'
    plot_heatmap_slices(heatmap, figure, scene=scene)
    print(f'slice figure: {figure}')
    return 0
