"""Offline heatmap: voxelization, weights, scene masking, determinism, shards, file safety."""

import dataclasses
import json
import pathlib
import zipfile

import coal
import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.model.collision import CollisionWorld, coal_geometry
from advocc_ros.heatmap import (HeatmapConfig, HeatmapError, build_heatmap, load_heatmap,
                                merge_heatmaps, sample_weights, save_heatmap)
from advocc_ros.model.robot import RobotSpec, load_robot
from advocc_ros.model.scene import Scene, make_box
from advocc_ros.model.voxels import occupied_mask

DATA = pathlib.Path(__file__).parent / 'data'
BOX_BOT = RobotSpec(urdf=str(DATA / 'box_bot.urdf'), srdf=str(DATA / 'box_bot.srdf'),
                    ee_link='slider')


@pytest.fixture(scope='module')
def small_table_heatmap(table_scene):
    return build_heatmap(table_scene, HeatmapConfig(samples=600), seed=3)


def test_one_link_cube_occupies_125_voxels_per_sample():
    # The 10 cm cube is offset by 1 cm in y and z, so voxel centres (odd multiples of 1 cm on a
    # grid snapped to 2 cm) sit at -4..4 cm from its centre: 5 x 5 x 5 per sample, whatever x.
    # gamma_man = 0: a 1-DoF arm has zero Yoshikawa manipulability, so weigh samples by 1.
    cfg = HeatmapConfig(samples=50, gamma_man=0.0, robot_only=True)
    heatmap = build_heatmap(Scene(robot=BOX_BOT), cfg, seed=1)
    assert heatmap.meta['valid_samples'] == 50
    assert heatmap.values.sum() == pytest.approx(125 * 50)
    # the swept volume is a bar along x: 5 x 5 voxels in y-z
    ys, zs = np.nonzero(heatmap.values.sum(axis=0))
    assert len(set(ys)) == 5 and len(set(zs)) == 5


@pytest.mark.parametrize('solid', ['panda_link5', 'cylinder', 'turned box', 'sphere'])
def test_convex_lut_is_the_half_space_test_of_every_cell(panda, solid):
    """The look-up table of a convex solid, built column by column, equals the plain test of
    every cell centre against every face of the hull."""
    import trimesh

    from advocc_ros.model.voxels import SolidLUT
    meshes = {'cylinder': trimesh.creation.cylinder(0.05, 0.2, 48),
              'turned box': trimesh.creation.box((0.1, 0.07, 0.2), trimesh.transformations.
                                                 euler_matrix(0.3, 0.5, 0.7)),
              'sphere': trimesh.creation.icosphere(3, 0.07)}
    if solid in meshes:
        mesh = meshes[solid]
    else:
        names = [panda.collision_model.geometryObjects[i].name
                 for i in range(panda.collision_model.ngeoms)]
        mesh = panda.link_meshes[next(i for i, n in enumerate(names) if solid in n)]
    hull = mesh.convex_hull
    assert abs(hull.volume - mesh.volume) <= 1e-3 * hull.volume  # the convex path
    lut = SolidLUT.from_mesh(mesh, 0.005)
    idx = np.argwhere(np.ones(lut.filled.shape, bool))
    centres = lut.origin_m + (idx + 0.5) * lut.pitch_m
    offsets = np.einsum('ij,ij->i', hull.face_normals, hull.triangles[:, 0])
    inside = np.all(centres @ hull.face_normals.T <= offsets + 1e-12, axis=1)
    np.testing.assert_array_equal(lut.filled[tuple(idx.T)], inside)
    assert inside.sum() > 100 and (~inside).sum() > 100


def test_link_bounds_are_the_link_meshes_bounds(panda):
    """``link_bounds_m`` (coal's local boxes, no mesh loading) equals the bounds trimesh gives."""
    lo, hi = panda.link_bounds_m
    np.testing.assert_array_equal(lo, [m.bounds[0] for m in panda.link_meshes])
    np.testing.assert_array_equal(hi, [m.bounds[1] for m in panda.link_meshes])


def test_link_tables_are_kept_on_disk_and_checked_when_read(panda, tmp_path, monkeypatch,
                                                            caplog):
    """A second process reads the tables the first one built; a damaged file is built again,
    and ``off`` keeps nothing on disk."""
    from advocc_ros.heatmap import LinkTables, build
    from advocc_ros.model.cache import CACHE_ENV
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(build, 'LINK_TABLES', build.BoundedCache('link look-up tables', 8))
    built = build.link_tables(panda, 0.005)
    [path] = (tmp_path / 'link_tables').iterdir()
    read = LinkTables.read(path, len(panda.link_names), 0.005)
    for name in LinkTables.ARRAYS:
        np.testing.assert_array_equal(getattr(read, name), getattr(built, name))
    with pytest.raises(ValueError, match='another robot or pitch'):
        LinkTables.read(path, len(panda.link_names), 0.01)

    path.write_bytes(b'not a zip file')
    build.LINK_TABLES.clear()
    again = build.link_tables(panda, 0.005)
    assert 'building them again' in caplog.text
    np.testing.assert_array_equal(again.data, built.data)
    assert LinkTables.read(path, len(panda.link_names), 0.005).data.sum() == built.data.sum()

    monkeypatch.setenv(CACHE_ENV, 'off')
    build.LINK_TABLES.clear()
    path.unlink()
    build.link_tables(panda, 0.005)
    assert not path.exists()


def test_h_is_zero_inside_scene_objects(small_table_heatmap, table_scene):
    heatmap = small_table_heatmap
    expected_blocked = occupied_mask(heatmap.grid, table_scene.shapes)
    assert np.array_equal(~heatmap.free, expected_blocked)
    assert expected_blocked.sum() > 1000  # the table alone is ~ 35 x 60 x 5 voxels
    assert np.all(heatmap.values[~heatmap.free] == 0)
    assert heatmap.values[heatmap.free].sum() > 0


def test_weights_match_hand_computed_manipulability_and_clearance(table_scene):
    robot = load_robot(table_scene.robot)
    world = CollisionWorld(robot, table_scene.shapes)
    cfg = HeatmapConfig()
    rng = np.random.default_rng(7)
    Q = robot.sample_q(rng, 400)
    Q = Q[~world.collisions_batch(Q)][:40]
    got = sample_weights(robot, world, Q, cfg)
    data = robot.model.createData()
    for q, w in zip(Q, got):
        J = pin.computeFrameJacobian(robot.model, data, q, robot.ee_frame,
                                     pin.LOCAL_WORLD_ALIGNED)
        m = np.sqrt(np.linalg.det(J @ J.T))
        # clearance by brute force over every (link, object) pair with coal directly
        pin.updateGeometryPlacements(robot.model, data, world.geom_model, world.geom_data, q)
        d = np.inf
        for li in range(world.n_links):
            T = world.geom_data.oMg[li]
            for shape in table_scene.shapes:
                Ts = shape.pose.to_se3()
                res = coal.DistanceResult()
                d = min(d, coal.distance(
                    world.geom_model.geometryObjects[li].geometry,
                    coal.Transform3s(T.rotation, T.translation), coal_geometry(shape),
                    coal.Transform3s(Ts.rotation, Ts.translation), coal.DistanceRequest(), res))
        expected = m / (m + 0.01) * min(max(d, 0) / 0.1, 1.0)
        # GJK stops at ~1e-6 m, i.e. 1e-5 of d_safe: compare to that precision
        assert w == pytest.approx(expected, rel=1e-4, abs=1e-6)


@pytest.mark.processes
def test_same_seed_same_heatmap_for_any_worker_count(table_scene):
    cfg = HeatmapConfig(samples=1200)
    a = build_heatmap(table_scene, cfg, seed=11, workers=1)
    b = build_heatmap(table_scene, cfg, seed=11, workers=2)
    c = build_heatmap(table_scene, cfg, seed=12, workers=1)
    assert np.array_equal(a.values, b.values)
    assert not np.array_equal(a.values, c.values)
    timing = {'build_s', 'created_unix', 'workers'}
    assert {k: v for k, v in a.meta.items() if k not in timing} == \
        {k: v for k, v in b.meta.items() if k not in timing}


def test_shards_merge_to_the_full_build(table_scene, tmp_path):
    cfg = HeatmapConfig(samples=2500)  # 3 chunks
    full = build_heatmap(table_scene, cfg, seed=5)
    shards = [build_heatmap(table_scene, cfg, seed=5, shard=(i, 2)) for i in range(2)]
    for i, shard in enumerate(shards):
        save_heatmap(shard, tmp_path / f's{i}.npz')
    merged = merge_heatmaps([load_heatmap(tmp_path / f's{i}.npz') for i in range(2)])
    np.testing.assert_allclose(merged.values, full.values, rtol=1e-12)
    assert merged.meta['valid_samples'] == 2500
    # different seeds add up; the same shard twice is refused
    other = build_heatmap(table_scene, HeatmapConfig(samples=300), seed=9)
    assert merge_heatmaps([full, other]).values.sum() == pytest.approx(
        full.values.sum() + other.values.sum())
    with pytest.raises(HeatmapError, match='counted twice'):
        merge_heatmaps([shards[0], shards[0]])


def test_merge_refuses_other_scene_or_robot(small_table_heatmap, table_scene):
    box = make_box('b', [0.5, 0, 0.2], [0.1, 0.1, 0.1])
    other_scene = table_scene.without_objects().with_objects([box])
    other = build_heatmap(other_scene, HeatmapConfig(samples=100), seed=8)
    with pytest.raises(HeatmapError, match='differ'):
        merge_heatmaps([small_table_heatmap, other])


def test_round_trip_and_corrupted_files_are_rejected(small_table_heatmap, tmp_path, panda):
    path = tmp_path / 'h.npz'
    save_heatmap(small_table_heatmap, path)
    loaded = load_heatmap(path, robot_hash=panda.hash)
    assert np.array_equal(loaded.values, small_table_heatmap.values)
    summary = loaded.summary()
    assert summary['valid_samples'] == 600 and summary['voxel'] == 0.02
    assert summary['shape'] == list(loaded.grid.shape) and summary['build_s'] > 0
    assert loaded.grid == small_table_heatmap.grid
    raw = path.read_bytes()

    (tmp_path / 'trunc.npz').write_bytes(raw[: len(raw) // 2])
    with pytest.raises(HeatmapError, match='corrupted or truncated'):
        load_heatmap(tmp_path / 'trunc.npz')
    flipped = bytearray(raw)
    flipped[len(raw) // 2] ^= 0xFF
    (tmp_path / 'flip.npz').write_bytes(bytes(flipped))
    with pytest.raises(HeatmapError):
        load_heatmap(tmp_path / 'flip.npz')
    (tmp_path / 'empty.npz').write_bytes(b'')
    with pytest.raises(HeatmapError):
        load_heatmap(tmp_path / 'empty.npz')
    with pytest.raises(HeatmapError, match='another robot|not this robot'):
        load_heatmap(path, robot_hash='0' * 16)
    with pytest.raises(HeatmapError, match='cannot read'):
        load_heatmap(tmp_path / 'missing.npz')


def test_pickled_arrays_are_never_loaded(tmp_path):
    path = tmp_path / 'evil.npz'
    np.savez(path, format_version=np.array(1), origin_m=np.zeros(3), voxel_m=np.array(0.02),
             shape=np.array([2, 2, 2]), values=np.array([{'x': 1}], dtype=object),
             free=np.ones((2, 2, 2), bool), meta_json=np.frombuffer(b'{}', np.uint8))
    with pytest.raises(HeatmapError):
        load_heatmap(path)


def test_bad_values_and_versions_are_rejected(small_table_heatmap, tmp_path):
    path = tmp_path / 'neg.npz'
    bad = small_table_heatmap.values.copy()
    bad[0, 0, 0] = -1
    arrays = dict(format_version=np.array(1),
                  origin_m=np.asarray(small_table_heatmap.grid.origin_m),
                  voxel_m=np.array(0.02), shape=np.asarray(small_table_heatmap.grid.shape),
                  values=bad, free=small_table_heatmap.free,
                  meta_json=np.frombuffer(json.dumps({}).encode(), np.uint8))
    np.savez(path, **arrays)
    with pytest.raises(HeatmapError, match='negative or non-finite'):
        load_heatmap(path)
    arrays['values'] = small_table_heatmap.values
    arrays['format_version'] = np.array(99)
    np.savez(path, **arrays)
    with pytest.raises(HeatmapError, match='format version 99'):
        load_heatmap(path)


def test_atomic_save_keeps_previous_file_on_failure(small_table_heatmap, tmp_path, monkeypatch):
    path = tmp_path / 'h.npz'
    save_heatmap(small_table_heatmap, path)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError('disk full')
    monkeypatch.setattr(np, 'savez_compressed', boom)
    with pytest.raises(OSError):
        save_heatmap(small_table_heatmap, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ['h.npz']  # no temporary left behind
    assert zipfile.is_zipfile(path)


def test_config_rejects_nonsense():
    for bad in (dict(samples=0), dict(voxel_m=float('nan')), dict(voxel_m=-0.02),
                dict(kappa=0), dict(d_safe_m=-1)):
        with pytest.raises(ValueError):
            HeatmapConfig(**bad)


def test_lut_pitch_comes_from_the_file(small_table_heatmap, table_scene, tmp_path, panda):
    """The attack rasterizes the robot with the tables the build used, not a guessed pitch."""
    from advocc_ros.attack import search_region
    from advocc_ros.heatmap import save_heatmap
    from advocc_ros.kinematics.ik import start_configuration

    coarse = build_heatmap(table_scene, HeatmapConfig(samples=50, lut_pitch_fraction=0.5),
                           seed=3)
    save_heatmap(coarse, tmp_path / 'coarse.npz')
    loaded = load_heatmap(tmp_path / 'coarse.npz')
    assert loaded.lut_pitch_m == pytest.approx(0.5 * loaded.grid.voxel_m)
    region = search_region(loaded, panda, table_scene.objects,
                           start_configuration(table_scene, panda), table_scene.goal)
    assert region.lut_pitch_m == pytest.approx(0.01)
    # a file written before the pitch was recorded reads at the documented default
    old = dict(small_table_heatmap.meta, params={})
    save_heatmap(dataclasses.replace(small_table_heatmap, meta=old), tmp_path / 'old.npz')
    assert load_heatmap(tmp_path / 'old.npz').lut_pitch_m == pytest.approx(0.25 * 0.02)
    bad = dict(small_table_heatmap.meta, params={'lut_pitch_fraction': 'a quarter'})
    save_heatmap(dataclasses.replace(small_table_heatmap, meta=bad), tmp_path / 'bad.npz')
    with pytest.raises(HeatmapError, match='lut_pitch_fraction'):
        load_heatmap(tmp_path / 'bad.npz')


def test_a_links_rasterization_is_every_voxel_centre_inside_its_table(panda):
    """The kernel visits a link's voxels only inside its rotated bounding box and, in each
    column, the span where its table can be (``link_column``, kernels/voxels.c): at random
    placements (and axis-aligned ones, whose column direction has exact zeros) it marks exactly
    the voxel centres of that box inside the link's table, as testing every centre of the grid
    with numpy (the same arithmetic) does: the column spans drop none."""
    from advocc_ros.heatmap.build import link_tables

    tables = link_tables(panda, 0.005)
    n_links = len(tables.shape)
    rng = np.random.default_rng(5)
    voxel, origin, shape = 0.02, np.array([-0.41, -0.37, -0.29]), (61, 61, 61)
    centres = origin + (np.indices(shape).reshape(3, -1).T + 0.5) * voxel
    rotations = [pin.exp3(rng.normal(size=3) * 2.0) for _ in range(60)] + [np.eye(3)] * 4
    inside = 0
    for n, r in enumerate(rotations):
        li = n % n_links
        t = rng.uniform(0.1, 1.0, size=3)
        mask = tables.rasterize(np.zeros(shape, bool), origin, voxel,
                                np.repeat(r[None], n_links, 0), np.repeat(t[None], n_links, 0),
                                links=[li])
        p = centres - t
        cell = [np.floor((r[0, m] * p[:, 0] + r[1, m] * p[:, 1] + r[2, m] * p[:, 2]
                          - tables.origin[li, m]) * (1.0 / tables.pitch)) for m in range(3)]
        ok = np.all([(c >= 0) & (c < tables.shape[li, m]) for m, c in enumerate(cell)], axis=0)
        gx, gy, gz = (np.where(ok, c, 0).astype(np.int64) for c in cell)
        sy, sz = tables.shape[li, 1], tables.shape[li, 2]
        expected = ok & (tables.data[tables.offset[li] + (gx * sy + gy) * sz + gz] != 0)
        index = np.indices(shape).reshape(3, -1)
        for a in range(3):  # the link's rotated bounding box, as the kernel bounds it
            c, e = t[a], 0.0
            for b in range(3):
                c += r[a, b] * 0.5 * (tables.box_lo[li, b] + tables.box_hi[li, b])
                e += abs(r[a, b]) * 0.5 * (tables.box_hi[li, b] - tables.box_lo[li, b])
            lo = np.ceil((c - e - origin[a]) / voxel - 0.5)
            hi = np.floor((c + e - origin[a]) / voxel - 0.5)
            expected &= (index[a] >= lo) & (index[a] <= hi)
        assert np.array_equal(mask.ravel(), expected), (n, li)
        inside += int(expected.sum())
    assert inside > 1000  # the links were in the window
