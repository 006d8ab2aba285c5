"""``advocc view``: one offline HTML page showing a scene, its attack and its paths in 3D."""

from __future__ import annotations

import argparse
import pathlib

from advocc_ros.cli import UserError
from advocc_ros.commands.common import add_scene_args, describe, scene_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('view', help='a self-contained 3D page of a scene, its boxes, heatmap '
                       'and paths', description=describe(__doc__))
    add_scene_args(p)
    p.add_argument('--obstacles', metavar='FILE',
                   help='obstacles file of `advocc attack` (boxes numbered in pick order; its '
                        'witness path FILE.witness.yaml is shown when present)')
    p.add_argument('--witness', metavar='FILE',
                   help='witness path file (advocc_witness: joint_names, waypoints [rad], '
                        'locked)')
    p.add_argument('--heatmap', metavar='FILE', help='heatmap .npz: its hottest voxels')
    p.add_argument('--audit', metavar='DIR',
                   help='audit folder of `advocc audit`: its boxes, answer and PSR figure '
                        '(its heatmap too, unless --heatmap is given)')
    p.add_argument('--planner', default='rrtconnect',
                   help='planner of the planned path (default %(default)s; "none": no path)')
    p.add_argument('--plan-time', type=float, default=2.0,
                   help='budget of the planned path [s] (default %(default)s)')
    p.add_argument('--out', required=True, metavar='FILE', help='HTML file to write')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from advocc_ros.attack import load_obstacles
    from advocc_ros.view.scene_page import (audit_view_html, load_witness_path, plan_path,
                                            scene_view_html, witness_beside)
    from advocc_ros.fileio import atomic_write_text
    from advocc_ros.heatmap import HeatmapError, load_heatmap
    from advocc_ros.model.robot import load_robot
    from advocc_ros.planning.types import PlanningConfig, planner_class_name

    if args.obstacles and args.audit:
        raise UserError('give --obstacles or --audit, not both (an audit has its own boxes)')
    if args.planner != 'none' and planner_class_name(args.planner) is None:
        raise UserError(f'unknown planner {args.planner!r}; e.g. rrtconnect, prmstar, none')
    if not 0 < args.plan_time <= PlanningConfig().max_time_budget_s:
        raise UserError(f'--plan-time must be in (0, {PlanningConfig().max_time_budget_s:g}] s')
    scene = scene_from_args(args)
    robot = load_robot(scene.robot)
    boxes = ()
    witness_file = args.witness
    if args.obstacles:
        boxes, _ = load_obstacles(args.obstacles)
        witness_file = witness_file or witness_beside(args.obstacles)
    heatmap_file = args.heatmap
    if heatmap_file is None and args.audit:
        found = pathlib.Path(args.audit) / f'heatmap_{scene.name}.npz'
        heatmap_file = found if found.is_file() else None
    try:
        heatmap = load_heatmap(heatmap_file, robot_hash=robot.hash) if heatmap_file else None
    except HeatmapError as exc:
        raise UserError(str(exc)) from None
    witness = load_witness_path(witness_file, robot) if witness_file else None
    planned = None
    if args.planner != 'none' and scene.start is not None and scene.goal is not None:
        planned = plan_path(scene, args.planner, args.plan_time)
    if args.audit:
        page = audit_view_html(args.audit, scene, heatmap, planned, witness)
    else:
        page = scene_view_html(scene, tuple(boxes), heatmap, planned, witness)
    atomic_write_text(args.out, page)
    print(f'view: {args.out} ({len(page) / 1e6:.1f} MB; open it in a browser, no network '
          'needed)')
    return 0
