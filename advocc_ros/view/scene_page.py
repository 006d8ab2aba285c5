"""``advocc view`` and the audit's ``audit.html``: an attack seen in 3D, in one offline page.

The page shows the robot at its start and at a goal configuration, the scene's objects (sensed
clouds as points), the boxes numbered in pick order, the hottest heatmap voxels coloured by H,
the goal region as a translucent box, and as animations a planned path (planned on the scene
without the boxes: the motion the boxes are meant to break) and a witness path when one is
given (a path that exists despite the boxes). No ROS; the page itself is ``view_page``.
"""

from __future__ import annotations

import dataclasses
import html
import json
import pathlib

import numpy as np
import pinocchio as pin
import trimesh

from advocc_ros.view.page import ViewBuilder, legend_html, page_html, png_data_uri
from advocc_ros.model.scene import Scene, SceneObject, make_box
from advocc_ros.model.pose import SceneError

TOP_PERCENTILE = 90.0
"""Heatmap voxels drawn: those at or above this percentile of the non-zero H (the top 10 %)."""
MAX_VOXELS = 4000
"""At most this many (the hottest) voxels are drawn, to keep the page small."""
STEP_RAD = 0.04
"""Joint-space distance between two animation frames [rad]."""
MAX_FRAMES = 300

COLORS = {'start': (0.55, 0.55, 0.6), 'goal': (0.2, 0.75, 0.3), 'planned': (0.15, 0.4, 0.95),
          'witness': (0.65, 0.2, 0.85), 'scene': (0.72, 0.66, 0.58), 'cloud': (0.2, 0.5, 0.9),
          'box': (0.9, 0.12, 0.1), 'region': (0.1, 0.85, 0.25)}


@dataclasses.dataclass(frozen=True)
class RobotPath:
    """Arm configurations (N, nq) [rad] in the robot's joint order, and what they are."""

    kind: str
    """planned | witness (its colour and node name)"""
    q: np.ndarray
    note: str = ''

    @property
    def label(self) -> str:
        return f'{self.kind} path'


def witness_beside(obstacles_file: str | pathlib.Path) -> pathlib.Path | None:
    """The witness file ``advocc attack`` writes beside an obstacles file, when there is one."""
    from advocc_ros.planning.witness import witness_file

    path = witness_file(obstacles_file)
    return path if path.is_file() else None


def load_witness_path(path: str | pathlib.Path, robot) -> RobotPath:
    """A witness file (``advocc_ros.planning.witness``) as configurations of ``robot``."""
    from advocc_ros.planning.witness import load_witness

    witness = load_witness(path)
    return RobotPath('witness', witness.configurations(robot),
                     f'{len(witness.waypoints)} waypoints from {path}')


def plan_path(scene: Scene, planner_id: str = 'rrtconnect', time_s: float = 2.0,
              seed: int = 0) -> RobotPath | str:
    """A path of ``planner_id`` on ``scene`` (in a watched worker process), or why none."""
    from advocc_ros.planning.worker import Planner
    from advocc_ros.planning.types import PlanningConfig
    from advocc_ros.kinematics.ik import start_configuration

    with Planner(scene, PlanningConfig()) as planner:
        robot_q = start_configuration(scene, planner.robot)
        result = planner.plan(robot_q, scene.goal, planner_id, time_s, seed)
    if not result.success:
        return f'{planner_id} found no path in {time_s:g} s ({result.status.name})'
    return RobotPath('planned', np.asarray(result.path, float),
                     f'{planner_id}, {len(result.path)} waypoints, '
                     f'{result.planning_time_s:.2f} s, on the scene without the boxes')


def dense_path(Q: np.ndarray, step_rad: float = STEP_RAD, max_frames: int = MAX_FRAMES
               ) -> np.ndarray:
    """Waypoints interpolated in joint space ``step_rad`` apart (at most ``max_frames``,
    evenly thinned), then held still for a second at the end."""
    from advocc_ros.planning.witness import witness_states

    frames = witness_states(Q, step_rad)
    if len(frames) > max_frames:
        frames = frames[np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    return np.vstack([frames, np.repeat(frames[-1:], 30, axis=0)])


def link_transforms(robot, q: np.ndarray) -> list[np.ndarray]:
    """``T_base_geom`` (4x4) of each robot collision geometry at ``q``."""
    data = robot.model.createData()
    gdata = pin.GeometryData(robot.collision_model)
    pin.updateGeometryPlacements(robot.model, data, robot.collision_model, gdata,
                                 np.asarray(q, float))
    return [np.array(T.homogeneous) for T in gdata.oMg]


def _draw_robot(view: ViewBuilder, robot, prefix: str, q: np.ndarray, rgb, opacity: float
                ) -> None:
    for name, mesh, T in zip(robot.link_names, robot.link_meshes, link_transforms(robot, q)):
        view.mesh(f'{prefix}/{name}', mesh.vertices, mesh.faces, rgb, opacity, T)


def _animate_robot(view: ViewBuilder, robot, prefix: str, path: RobotPath, rgb) -> None:
    frames = [link_transforms(robot, q) for q in dense_path(path.q)]
    _draw_robot(view, robot, prefix, path.q[0], rgb, 0.7)
    for k, name in enumerate(robot.link_names):
        view.keyframes(f'{prefix}/{name}', [f[k] for f in frames])


def _draw_objects(view: ViewBuilder, objects, prefix: str, rgb, opacity: float = 1.0) -> None:
    for obj in objects:
        for k, shape in enumerate(obj.shapes):
            path = f'{prefix}/{obj.id}_{k}'
            if shape.kind == 'cloud':
                T = shape.pose.to_se3()
                pts = np.asarray(shape.vertices) @ T.rotation.T + T.translation
                view.points(path, pts, np.tile(COLORS['cloud'], (len(pts), 1)), shape.dims[0])
            else:
                mesh = shape.trimesh()
                view.mesh(path, mesh.vertices, mesh.faces, rgb, opacity)


def _draw_heatmap(view: ViewBuilder, heatmap) -> str:
    """The hottest voxels as points coloured by H (viridis); returns the legend's text."""
    from matplotlib import colormaps

    from advocc_ros.heatmap import hottest_voxels

    centers, H = hottest_voxels(heatmap, TOP_PERCENTILE)
    if len(H) == 0:
        return 'heatmap: no voxel with H > 0'
    order = np.argsort(H)[::-1][:MAX_VOXELS]
    centers, H = centers[order], H[order]
    logH = np.log(H)  # H spans orders of magnitude: colour by its logarithm
    span = float(logH.max() - logH.min()) or 1.0
    colors = colormaps['viridis']((logH - logH.min()) / span)[:, :3]
    view.points('heatmap', centers, colors, heatmap.grid.voxel_m * 0.8)
    return (f'heatmap: the {len(H)} hottest voxels (top {100 - TOP_PERCENTILE:g} % of H > 0'
            f'{", capped" if len(order) == MAX_VOXELS else ""}), purple (low) to yellow '
            f'(high H, max {H.max():.3g}; log scale)')


def _draw_goal_region(view: ViewBuilder, goal) -> None:
    half = np.asarray(goal.position_tolerance_m, float)
    # The box is drawn at least 1 cm thick so a zero tolerance stays visible.
    box = trimesh.creation.box(extents=np.maximum(2 * half, 0.01))
    view.mesh('goal_region', box.vertices, box.faces, COLORS['region'], 0.35,
              goal.center.to_se3().homogeneous)


def _boxes_table(boxes) -> str:
    rows = ['<table><tr><th>#</th><th>id</th><th>centre x, y, z [m]</th></tr>']
    for i, obj in enumerate(boxes, start=1):
        c = obj.shapes[0].pose.position_m
        rows.append(f'<tr><td>{i}</td><td>{html.escape(obj.id)}</td>'
                    f'<td>{c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}</td></tr>')
    return '\n'.join(rows + ['</table>'])


def scene_view_html(scene: Scene, boxes: tuple[SceneObject, ...] = (), heatmap=None,
                    planned: RobotPath | str | None = None, witness: RobotPath | None = None,
                    title: str | None = None, extra_html: str = '') -> str:
    """The page for ``scene`` with ``boxes`` (pick order) and whatever else is given;
    ``planned`` may be the reason no path was planned. ``extra_html`` (trusted) goes under
    the legend."""
    from advocc_ros.kinematics.ik import goal_configuration, start_configuration
    from advocc_ros.model.robot import load_robot

    robot = load_robot(scene.robot)
    view = ViewBuilder()
    legend = [(f'scene objects ({len(scene.objects)})', COLORS['scene'])]
    _draw_objects(view, scene.objects, 'scene', COLORS['scene'])
    if boxes:
        _draw_objects(view, boxes, 'boxes', COLORS['box'])
        for i, obj in enumerate(boxes, start=1):
            lo, hi = obj.shapes[0].bounds_m()
            view.label(f'box_labels/{i}', str(i), [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2,
                                                   hi[2] + 0.06])
        legend.append((f'adversarial boxes, numbered in pick order ({len(boxes)})',
                       COLORS['box']))
    notes = []
    if heatmap is not None:
        notes.append(_draw_heatmap(view, heatmap))
    if scene.goal is not None:
        _draw_goal_region(view, scene.goal)
        legend.append(('goal region (position tolerance)', COLORS['region']))
    q_start = start_configuration(scene, robot) if scene.start is not None else None
    if q_start is not None:
        _draw_robot(view, robot, 'robot_start', q_start, COLORS['start'], 1.0)
        legend.append(('robot at the start', COLORS['start']))
    paths = [p for p in (planned, witness) if isinstance(p, RobotPath)]
    q_goal, goal_note = None, ''
    if paths:
        q_goal, goal_note = paths[0].q[-1], f'end of the {paths[0].label}'
    elif scene.goal is not None and q_start is not None:
        q_goal = goal_configuration(robot, scene.goal, q_start)
        goal_note = 'inverse kinematics to the goal centre (collisions not checked)'
    if q_goal is not None:
        _draw_robot(view, robot, 'robot_goal', q_goal, COLORS['goal'], 0.3)
        legend.append((f'robot at a goal configuration ({goal_note})', COLORS['goal']))
    for path in paths:
        _animate_robot(view, robot, f'{path.kind}_path', path, COLORS[path.kind])
        legend.append((f'{path.label} (animated): {path.note}', COLORS[path.kind]))
    if isinstance(planned, str):
        notes.append(f'planned path: {planned}')
    side = [legend_html(legend)]
    side += [f'<p>{html.escape(n)}</p>' for n in notes]
    if boxes:
        side += ['<h2>Boxes in pick order</h2>', _boxes_table(boxes)]
    side += [extra_html, '<p>Drag to rotate, scroll to zoom, right-drag to pan; the panel at '
             'the top right of the view hides objects and replays the animations. Robot base '
             f'frame {html.escape(scene.frame)}, metres.</p>']
    return page_html(title or f'advocc view: {scene.name}', '\n'.join(side), view.commands())


def audit_boxes(audit: dict) -> tuple[SceneObject, ...]:
    """The audit's boxes in pick order (``audit.json``'s ``boxes``)."""
    return tuple(make_box(b['id'], b['center_m'], (b['size_m'],) * 3) for b in audit['boxes'])


def audit_view_html(audit_dir: str | pathlib.Path, scene: Scene, heatmap=None,
                    planned: RobotPath | str | None = None,
                    witness: RobotPath | None = None) -> str:
    """The page of an audit folder: its boxes, the answer and the PSR-per-budget figure."""
    from advocc_ros.audit.report import audit_answer

    folder = pathlib.Path(audit_dir)
    try:
        audit = json.loads((folder / 'audit.json').read_text())
    except (OSError, ValueError) as exc:
        raise SceneError(f'{folder / "audit.json"}: cannot read the audit ({exc})') from None
    if audit.get('scene_hash') not in (None, scene.objects_hash()):
        raise SceneError(f'{folder}: the audit was run on scene {audit.get("scene")!r} with '
                         f'other objects than {scene.name!r}; give the audit\'s scene')
    extra = ['<h2>Answer</h2>', f'<pre>{html.escape(audit_answer(audit))}</pre>']
    figure = folder / 'audit_psr.png'
    if figure.is_file():
        extra += ['<h2>PSR per budget</h2>',
                  f'<img alt="PSR per budget" src="{png_data_uri(figure)}">']
    return scene_view_html(scene, audit_boxes(audit), heatmap, planned, witness,
                           title=f'advocc audit: {scene.name}', extra_html='\n'.join(extra))


def write_audit_view(audit_dir: str | pathlib.Path, scene: Scene, heatmap=None,
                     planner_id: str = 'rrtconnect', time_s: float = 2.0) -> pathlib.Path:
    """Write ``audit.html`` into the audit folder (with a planned path, and the witness
    ``audit.witness.yaml`` when the folder has one); returns its path."""
    from advocc_ros.fileio import atomic_write_text
    from advocc_ros.model.robot import load_robot

    folder = pathlib.Path(audit_dir)
    witness_file = witness_beside(folder / 'audit.yaml')
    witness = load_witness_path(witness_file, load_robot(scene.robot)) if witness_file else None
    page = audit_view_html(folder, scene, heatmap, plan_path(scene, planner_id, time_s),
                           witness)
    atomic_write_text(folder / 'audit.html', page)
    return folder / 'audit.html'
