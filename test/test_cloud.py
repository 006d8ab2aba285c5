"""Sensed point clouds as scene objects: files, limits, octree agreement, and the sensed
table_pick (plans, heatmap, task attack)."""

import numpy as np
import pytest

from advocc_ros.limits import MAX_CLOUD_POINTS, MAX_CLOUD_RESOLUTION_M
from advocc_ros.model.cloud import cloud_octree, make_cloud_shape, read_cloud_file
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import load_scene, scene_from_data
from advocc_ros.scenes.sensing import sensed_scene, write_sensed_scene
from advocc_ros.model.shapes import cloud_cells
from advocc_ros.model.voxels import VoxelGrid, occupied_mask, points_in_shape


def sensed_table_path():
    from advocc_ros.paths import scene_path
    return scene_path('table_pick')


@pytest.fixture(scope='module')
def sensed_table():
    """table_pick with its objects replaced by one sensed cloud (deterministic)."""
    return sensed_scene(load_scene(sensed_table_path()))


def test_sensed_scene_is_deterministic_and_small(sensed_table):
    again = sensed_scene(load_scene(sensed_table_path()))
    assert again.objects_hash() == sensed_table.objects_hash()
    shape = sensed_table.shapes[0]
    assert shape.kind == 'cloud' and shape.dims == (0.02,)
    assert 20_000 < len(shape.vertices) < 200_000


def test_ply_and_pcd_files_round_trip(tmp_path, sensed_table):
    path = write_sensed_scene(load_scene(sensed_table_path()), tmp_path)
    loaded = load_scene(path)
    assert loaded.objects_hash() != '' and loaded.shapes[0].kind == 'cloud'
    np.testing.assert_allclose(loaded.shapes[0].vertices, sensed_table.shapes[0].vertices,
                               atol=1e-6)
    import pypcd4

    pcd = tmp_path / 'c.pcd'
    pts = sensed_table.shapes[0].vertices[:500].astype(np.float32)
    pypcd4.PointCloud.from_xyz_points(pts).save(str(pcd))
    np.testing.assert_allclose(read_cloud_file(pcd), pts, atol=1e-6)


@pytest.mark.parametrize('points,resolution,message', [
    (np.zeros((0, 3)), 0.02, 'empty'),
    ([[0, 0, 0], [np.nan, 0, 0]], 0.02, 'NaN/inf'),
    ([[0, 0, 0], [np.inf, 0, 0]], 0.02, 'NaN/inf'),
    ([[0, 0, 0]], 0.0001, 'outside'),
    ([[0, 0, 0]], MAX_CLOUD_RESOLUTION_M * 2, 'outside'),
    ([[0, 0]], 0.02, '(N, 3)'),
])
def test_bad_clouds_are_refused(points, resolution, message):
    with pytest.raises(SceneError, match=message.replace('(', r'\(').replace(')', r'\)')):
        make_cloud_shape(points, resolution, where='objects[0]')


def test_too_many_points_are_refused(monkeypatch):
    import advocc_ros.model.cloud as cloud
    monkeypatch.setattr(cloud, 'MAX_CLOUD_POINTS', 10)
    with pytest.raises(SceneError, match='MAX_CLOUD_POINTS'):
        make_cloud_shape(np.zeros((11, 3)), 0.02)
    assert MAX_CLOUD_POINTS >= 1_000_000


def test_scene_file_errors_name_the_field(tmp_path):
    base = {'objects': [{'id': 'c', 'type': 'cloud', 'file': 'missing.ply'}]}
    with pytest.raises(SceneError, match=r'objects\[0\].file: .* not found'):
        scene_from_data(base, 's', tmp_path)
    (tmp_path / 'x.xyz').write_text('0 0 0\n')
    base['objects'][0]['file'] = 'x.xyz'
    with pytest.raises(SceneError, match='not a PLY or PCD'):
        scene_from_data(base, 's', tmp_path)
    (tmp_path / 'bad.ply').write_text('not a ply')
    base['objects'][0]['file'] = 'bad.ply'
    with pytest.raises(SceneError, match='could not be read'):
        scene_from_data(base, 's', tmp_path)
    inline = {'objects': [{'id': 'c', 'type': 'cloud', 'points': [[0, 0, 0]],
                           'resolution': 0.05}]}
    scene = scene_from_data(inline, 's')
    assert scene_from_data(scene.to_data(), 's').objects_hash() == scene.objects_hash()


def test_voxel_occupancy_matches_the_octree_leaves():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.2, 0.2, (400, 3))
    pose = Pose((0.5, 0.1, 0.3), (0.0, 0.0, 0.3826834, 0.9238795))
    shape = make_cloud_shape(pts, 0.03, pose)
    boxes = np.array(cloud_octree(shape).toBoxes())
    leaves = {tuple(c) for c in np.floor(boxes[:, :3] / 0.03 + 1e-6).astype(int)}
    assert leaves == {tuple(c) for c in cloud_cells(pts, 0.03)}
    # Voxel centres inside a leaf are occupied, others not; bounds contain every leaf.
    T = pose.to_se3()
    centres_local = (np.array(sorted(leaves)) + 0.5) * 0.03
    centres = centres_local @ T.rotation.T + T.translation
    assert points_in_shape(shape, centres).all()
    assert not points_in_shape(shape, centres + 10.0).any()
    lo, hi = shape.bounds_m()
    assert np.all(centres >= lo) and np.all(centres <= hi)
    grid = VoxelGrid((0.0, -0.4, -0.1), 0.02, (50, 50, 40))
    mask = occupied_mask(grid, [shape])
    assert mask.any()
    assert points_in_shape(shape, grid.centers(np.argwhere(mask))).all()
    assert len(shape.trimesh().faces) == 12 * len(leaves)


def test_collision_world_uses_the_octree(panda, sensed_table):
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.kinematics.ik import start_configuration
    world = CollisionWorld(panda, sensed_table.shapes)
    q = start_configuration(sensed_table, panda)
    assert world.is_valid(q)
    d = world.scene_distance(q)
    assert 0.05 < d < 1.0
    assert world.scene_distance(q, upto_m=0.5) == d  # only the pairs within 0.5 m: same min
    assert world.scene_distance(q, upto_m=0.01) == 0.01  # none within 1 cm
    q_low = q.copy()
    q_low[1], q_low[3] = 1.2, -0.5  # shoulder down: the hand goes through the table top
    assert world.in_collision(q_low)


@pytest.mark.slow
def test_sensed_table_pick_plans_builds_a_heatmap_and_takes_a_task_attack(panda, sensed_table):
    from advocc_ros.attack import attack
    from advocc_ros.evaluation.runner import evaluate_planner
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap
    from advocc_ros.kinematics.ik import start_configuration

    heatmap = build_heatmap(sensed_table, HeatmapConfig(samples=400), seed=1)
    assert heatmap.values.sum() > 0 and not heatmap.free.all()
    q_init = start_configuration(sensed_table, panda)
    result = attack(heatmap, panda, sensed_table.objects, q_init, sensed_table.goal, 3,
                    method='task', seed=0)
    assert len(result.obstacles) == 3, result.message
    row = evaluate_planner(sensed_table, 'rrtconnect', trials=8, time_budget_s=5.0, seed=0)
    assert row['psr'] >= 0.75, row
