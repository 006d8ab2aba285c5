"""The obstacles file (``format: advocc_obstacles``): its one writer and its reader.

Keys, in this order: ``format``, ``version``, ``status``, ``message``, ``method``, ``budget``,
``box_size_m``, ``masses``, ``total_mass``, ``compute_ms``, ``goal_policy``,
``goal_valid_fraction``, ``solvable`` (verdict, message, goal probe counts), ``scene`` (``name``,
``objects_hash``, ...), optionally ``heatmap``, then the writer's own keys (``seed``,
``source``, ...), and last ``objects`` (the scene-file format). Unknown values are null.
Older files wrote ``compute_s`` instead of ``compute_ms`` and could lack ``box_size_m``; the
reader fills both in.
"""

from __future__ import annotations

import pathlib
from typing import Any, Sequence

from advocc_ros.attack.types import AttackResult
from advocc_ros.heatmap import Heatmap
from advocc_ros.model.pose import SceneError
from advocc_ros.model.scene import (SceneObject, objects_from_data, objects_to_data, read_yaml,
                                    save_yaml_atomic)

OBSTACLES_FORMAT = 'advocc_obstacles'
OBSTACLES_VERSION = 1


def _box_size(objects: Sequence[SceneObject]) -> float | None:
    """The edge of the first box (an attack's boxes are cubes of one size), or None."""
    shape = objects[0].shapes[0] if objects and objects[0].shapes else None
    return float(shape.dims[0]) if shape is not None and shape.kind == 'box' else None


def obstacles_file_data(objects: Sequence[SceneObject], method: str, budget: int,
                        status: str | None = None, message: str | None = None,
                        box_size_m: float | None = None, masses: Sequence[float] | None = None,
                        total_mass: float | None = None, compute_ms: float | None = None,
                        scene: dict | None = None, heatmap: Heatmap | None = None,
                        extra: dict | None = None, goal_policy: str | None = None,
                        goal_valid_fraction: float | None = None,
                        solvable: dict | None = None) -> dict:
    """The YAML mapping of an obstacles file (every writer builds it here).

    ``box_size_m`` defaults to the first box's edge; ``scene``: ``{'name', 'objects_hash'}``
    and anything else to record about it; ``extra``: the writer's own keys.
    """
    data: dict[str, Any] = {
        'format': OBSTACLES_FORMAT, 'version': OBSTACLES_VERSION,
        'status': status, 'message': message, 'method': method, 'budget': budget,
        'box_size_m': float(box_size_m) if box_size_m is not None else _box_size(objects),
        'masses': None if masses is None else [float(m) for m in masses],
        'total_mass': None if total_mass is None else float(total_mass),
        'compute_ms': None if compute_ms is None else round(float(compute_ms), 3),
        'goal_policy': goal_policy,
        'goal_valid_fraction': (None if goal_valid_fraction is None
                                else round(float(goal_valid_fraction), 6)),
        'solvable': solvable,
        'scene': dict(scene) if scene is not None else {'name': None, 'objects_hash': None},
    }
    if heatmap is not None:
        data['heatmap'] = {'robot_hash': heatmap.meta.get('robot_hash'),
                           'scene_hash': heatmap.meta.get('scene_hash'),
                           'robot_only': heatmap.robot_only,
                           'valid_samples': heatmap.meta.get('valid_samples'),
                           'seeds': heatmap.meta.get('seeds'), **heatmap.grid.to_data()}
    data.update(extra or {})
    data['objects'] = objects_to_data(objects)
    return data


def obstacles_data(result: AttackResult, heatmap: Heatmap | None = None,
                   scene_name: str | None = None, scene_hash: str | None = None,
                   extra: dict | None = None) -> dict:
    """The obstacles file of an :class:`AttackResult` (see :func:`obstacles_file_data`)."""
    return obstacles_file_data(
        result.obstacles, result.method, result.budget, result.status.value, result.message,
        result.box_size_m, result.masses, result.total_mass, result.compute_s * 1e3,
        {'name': scene_name, 'objects_hash': scene_hash}, heatmap, extra,
        result.goal_policy or None, result.goal_valid_fraction,
        result.solvable.to_json() if result.solvable is not None else None)


def save_obstacles(path: str | pathlib.Path, data: dict) -> None:
    """Write an obstacles file atomically (see :func:`obstacles_file_data`)."""
    save_yaml_atomic(path, data)


def obstacles_meta(data: dict) -> dict:
    """The metadata of an obstacles mapping, older files' keys brought up to date."""
    meta = {k: v for k, v in data.items() if k != 'objects'}
    if meta.get('compute_ms') is None and isinstance(meta.get('compute_s'), (int, float)):
        meta['compute_ms'] = round(float(meta['compute_s']) * 1e3, 3)
    return meta


def load_obstacles(path: str | pathlib.Path) -> tuple[tuple[SceneObject, ...], dict]:
    """(objects, metadata) of an obstacles file; errors name the file and field."""
    path = pathlib.Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict) or 'objects' not in data:
        raise SceneError(f'{path}: expected a mapping with objects: [...]')
    objects = objects_from_data(data['objects'], f'{path}.objects', path.parent)
    meta = obstacles_meta(data)
    if meta.get('box_size_m') is None:
        meta['box_size_m'] = _box_size(objects)
    return objects, meta


__all__ = ['OBSTACLES_FORMAT', 'OBSTACLES_VERSION', 'load_obstacles', 'obstacles_data',
           'obstacles_file_data', 'obstacles_meta', 'save_obstacles']
