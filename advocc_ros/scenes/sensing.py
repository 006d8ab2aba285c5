"""Simulated sensing: a scene's objects replaced by one noisy point cloud of their surfaces.

Stands in for a scene reconstructed from an RGB-D camera (the paper's real-robot deployment):
surfaces are sampled about every ``spacing_m``, faces pointing down (unseen from above: the
table's underside, object bottoms) are dropped, and each point gets Gaussian noise. Seeded, so
tests and the CLI (``advocc scenes sense``) get the same cloud every time.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import trimesh

from advocc_ros.model.cloud import DEFAULT_RESOLUTION_M, make_cloud_shape
from advocc_ros.model.scene import Scene, SceneObject, save_yaml_atomic


@dataclasses.dataclass(frozen=True)
class SensingConfig:
    """How the simulated camera sees the scene."""

    spacing_m: float = 0.005
    """Mean distance between surface samples [m] (well below the octree resolution)."""
    noise_m: float = 0.001
    """Standard deviation of the Gaussian noise added to each point [m]."""
    resolution_m: float = DEFAULT_RESOLUTION_M
    """Octree leaf edge of the sensed cloud [m]."""
    min_normal_z: float = -0.5
    """Faces whose unit normal has a z below this are unseen (seen from above)."""
    seed: int = 0


def sensed_points(scene: Scene, cfg: SensingConfig = SensingConfig()) -> np.ndarray:
    """(N, 3) noisy surface samples of every object of ``scene``, in the base frame."""
    rng = np.random.default_rng(cfg.seed)
    chunks = []
    for shape in scene.shapes:
        mesh = shape.trimesh()
        seen = mesh.face_normals[:, 2] >= cfg.min_normal_z
        if not seen.any():
            continue
        part = mesh.submesh([np.flatnonzero(seen)], append=True)
        count = max(int(np.ceil(part.area / cfg.spacing_m ** 2)), 1)
        points, _ = trimesh.sample.sample_surface(part, count, seed=int(rng.integers(2 ** 31)))
        chunks.append(points + rng.normal(0.0, cfg.noise_m, points.shape))
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))


def sensed_scene(scene: Scene, cfg: SensingConfig = SensingConfig(),
                 cloud_id: str = 'sensed') -> Scene:
    """``scene`` with its objects replaced by one cloud object of their sensed surfaces."""
    shape = make_cloud_shape(sensed_points(scene, cfg), cfg.resolution_m, where=cloud_id)
    return dataclasses.replace(scene, objects=(SceneObject(cloud_id, (shape,)),),
                               name=f'{scene.name}_sensed')


def write_sensed_scene(scene: Scene, out_dir: str | pathlib.Path,
                       cfg: SensingConfig = SensingConfig()) -> pathlib.Path:
    """Write ``<name>_sensed.yaml`` and its cloud ``<name>_sensed.ply`` (binary PLY) into
    ``out_dir``; returns the YAML path."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sensed = sensed_scene(scene, cfg)
    shape = sensed.objects[0].shapes[0]
    ply = out / f'{sensed.name}.ply'
    tmp = ply.with_suffix('.ply.tmp')
    trimesh.PointCloud(shape.vertices).export(str(tmp), file_type='ply')
    tmp.replace(ply)
    data = sensed.to_data()
    data['objects'] = [{'id': 'sensed', 'type': 'cloud', 'file': ply.name,
                        'resolution': float(shape.dims[0]), 'pose': shape.pose.to_data()}]
    path = out / f'{sensed.name}.yaml'
    save_yaml_atomic(path, data)
    return path
