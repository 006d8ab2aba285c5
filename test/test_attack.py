"""Online attack: greedy against brute force, constraints of every output, statuses, files."""

import dataclasses
import itertools
import math

import coal
import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.attack import (AttackConfig, AttackStatus, attack, box_distance, box_sum,
                               greedy_cover, load_obstacles, obstacles_data, random_cover,
                               save_obstacles, search_region)
from advocc_ros.model.collision import CollisionWorld, coal_geometry
from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose
from advocc_ros.model.scene import make_box, objects_from_data, read_yaml

# ---------------------------------------------------------------------------------------------
# Synthetic arrays: brute force is computable


def _cube_mass(W, c, k):
    sl = tuple(slice(max(c[a] - k, 0), c[a] + k + 1) for a in range(3))
    return W[sl].sum()


def _union_mass(W, picks, k):
    covered = np.zeros(W.shape, dtype=bool)
    for c in picks:
        covered[tuple(slice(max(c[a] - k, 0), c[a] + k + 1) for a in range(3))] = True
    return W[covered].sum()


def _synthetic(seed, n=6, density=0.3):
    rng = np.random.default_rng(seed)
    W = rng.gamma(0.5, 1.0, size=(n, n, n)) * (rng.random((n, n, n)) < 0.7)
    cand = rng.random((n, n, n)) < density
    return W, cand


def _brute_force(W, cand, k, M, d_min_vox):
    idx = [tuple(c) for c in np.argwhere(cand)]
    best = 0.0
    for m in range(1, M + 1):
        for combo in itertools.combinations(idx, m):
            if any(np.linalg.norm(np.subtract(a, b)) < d_min_vox - 1e-9
                   for a, b in itertools.combinations(combo, 2)):
                continue
            best = max(best, _union_mass(W, combo, k))
    return best


def test_box_sum_matches_direct_sums():
    W, _ = _synthetic(1, n=7)
    for k in (0, 1, 2):
        S = box_sum(W, k)
        for c in itertools.product(range(7), repeat=3):
            assert S[c] == pytest.approx(_cube_mass(W, c, k), rel=1e-12, abs=1e-12)


def test_box_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    mask = rng.random((9, 8, 7)) < 0.03
    voxel, half, max_m = 0.02, 0.025, 0.1
    D = box_distance(mask, voxel, half, max_m)
    crop = (slice(2, 7), slice(1, 8), slice(3, 5))
    assert np.array_equal(box_distance(mask, voxel, half, max_m, crop), D[crop])
    pts = np.argwhere(mask) * voxel
    for c in itertools.product(*map(range, mask.shape)):
        d = np.abs(pts - np.asarray(c) * voxel)
        true = np.min(np.linalg.norm(np.maximum(d - half, 0), axis=1)) if len(pts) else np.inf
        if true <= max_m:
            assert D[c] == pytest.approx(true, abs=1e-7)  # float32 squared distances
        else:
            assert D[c] > max_m


@pytest.mark.parametrize('seed', range(6))
def test_greedy_equals_brute_force_for_one_box(seed):
    W, cand = _synthetic(seed, n=7)
    picks, _ = greedy_cover(W, cand, 1, 1, 2.5)
    best = max(_cube_mass(W, c, 1) for c in np.argwhere(cand))
    assert picks[0][1] == pytest.approx(best, rel=1e-12)


@pytest.mark.parametrize('seed,budget', [(s, m) for s in range(4) for m in (2, 3)])
def test_greedy_reaches_the_bound_against_compatible_sets(seed, budget):
    """The voxel greedy's guarantee (docs/greedy.md): (1 - 1/e) of the best M-set of
    candidates that stay compatible with its picks (>= d_min from each, or a pick)."""
    W, cand = _synthetic(100 + seed, n=6, density=0.15)
    d_min = 2.0
    picks, _ = greedy_cover(W, cand, 1, budget, d_min)
    centres = [c for c, _ in picks]
    assert sum(m for _, m in picks) == pytest.approx(_union_mass(W, centres, 1), rel=1e-12)
    for a, b in itertools.combinations(centres, 2):
        assert np.linalg.norm(a - b) >= d_min
    compatible = cand.copy()
    for c in np.argwhere(cand):
        compatible[tuple(c)] = any(np.array_equal(c, p) for p in centres) or all(
            np.linalg.norm(c - p) >= d_min for p in centres)
    assert _union_mass(W, centres, 1) >= (1 - 1 / math.e) * _brute_force(
        W, compatible, 1, budget, 0.0) - 1e-9


def test_greedy_respects_candidates_separation_and_rejections():
    W, cand = _synthetic(7, n=8, density=0.4)
    rejected = set()

    def accept(c):  # an exact check that vetoes every other candidate
        ok = (int(c.sum()) % 2) == 0
        if not ok:
            rejected.add(tuple(c))
        return ok

    picks, n_rej = greedy_cover(W, cand, 1, 6, 3.0, accept)
    assert n_rej == len(rejected) > 0
    for c, _ in picks:
        assert cand[tuple(c)] and int(c.sum()) % 2 == 0
    for (a, _), (b, _) in itertools.combinations(picks, 2):
        assert np.linalg.norm(a - b) >= 3.0


def test_random_cover_is_seeded_and_constrained():
    W, cand = _synthetic(9, n=8, density=0.4)
    a, _ = random_cover(W, cand, 1, 5, 2.0, np.random.default_rng(4))
    b, _ = random_cover(W, cand, 1, 5, 2.0, np.random.default_rng(4))
    c, _ = random_cover(W, cand, 1, 5, 2.0, np.random.default_rng(5))
    key = lambda picks: [tuple(p) for p, _ in picks]  # noqa: E731
    assert key(a) == key(b) and key(a) != key(c)
    for x, y in itertools.combinations([p for p, _ in a], 2):
        assert np.linalg.norm(x - y) >= 2.0
    assert all(cand[tuple(p)] for p, _ in a)


def test_few_candidates_stop_early():
    W, cand = _synthetic(2, n=6, density=0.0)
    cand[1, 1, 1] = cand[1, 1, 2] = True  # adjacent: d_min keeps only one
    picks, _ = greedy_cover(W, cand, 1, 3, 2.0)
    assert len(picks) == 1
    assert greedy_cover(W, np.zeros_like(cand), 1, 3, 2.0) == ([], 0)


# ---------------------------------------------------------------------------------------------
# The Panda task: real heatmaps (small), exact checks with coal


@pytest.fixture(scope='module')
def heatmaps(table_scene):
    return {'scene': build_heatmap(table_scene, HeatmapConfig(samples=400), seed=1),
            'robot_only': build_heatmap(table_scene, HeatmapConfig(samples=400, robot_only=True),
                                        seed=1)}


@pytest.fixture(scope='module')
def task(panda, table_scene):
    q = panda.q_from_names(list(table_scene.start), list(table_scene.start.values()))
    return q, table_scene.goal, table_scene.objects


def _distance(shape_a, T_a, geom_b, T_b):
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    return coal.distance(coal_geometry(shape_a), coal.Transform3s(T_a.rotation, T_a.translation),
                         geom_b, coal.Transform3s(T_b.rotation, T_b.translation), req, res)


def _assert_constraints(result, panda, heatmap, objects, q, goal, cfg):
    """Corridor, H > 0, box in V_free, clearances from robot and goal, no overlap, d_min."""
    world = CollisionWorld(panda)
    links = [(g.geometry, pin.SE3(T)) for g, T in zip(world.geom_model.geometryObjects,
                                                      world.link_placements(q))]
    T_ee = panda.ee_pose(q) * goal.tool_offset.to_se3()
    a, b = T_ee.translation, np.array(goal.center.position_m)
    goal_box = coal.Box(*np.maximum(2 * np.asarray(goal.position_tolerance_m), 1e-9))
    centres = result.centers_m
    grid = heatmap.grid
    k = int(math.floor(result.box_size_m / 2 / grid.voxel_m + 1e-9))
    scene_shapes = [s for o in objects for s in o.shapes]
    for obj, c in zip(result.obstacles, centres):
        shape = obj.shapes[0]
        assert shape.kind == 'box' and shape.dims == (result.box_size_m,) * 3
        T = shape.pose.to_se3()
        assert np.allclose(T.rotation, np.eye(3))
        t = np.clip((c - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        assert np.linalg.norm(c - (a + t * (b - a))) <= cfg.corridor_radius_m + 1e-9
        idx = grid.index_of(c)
        assert np.allclose(grid.centers(idx), c)
        assert heatmap.values[tuple(idx)] > 0
        block = tuple(slice(idx[i] - k, idx[i] + k + 1) for i in range(3))
        assert heatmap.free[block].all()
        for geom, T_link in links:
            assert _distance(shape, T, geom, T_link) >= cfg.d_safe_m - 1e-9
        assert _distance(shape, T, goal_box, goal.center.to_se3()) >= cfg.d_safe_m - 1e-9
        for s in scene_shapes:
            assert _distance(shape, T, coal_geometry(s), s.pose.to_se3()) > 0
    for x, y in itertools.combinations(centres, 2):
        assert np.linalg.norm(x - y) >= cfg.d_min_m - 1e-9


@pytest.mark.parametrize('method', ['ours', 'random'])
@pytest.mark.parametrize('flavour', ['scene', 'robot_only'])
def test_every_output_respects_every_constraint(panda, heatmaps, task, method, flavour):
    q, goal, objects = task
    cfg = AttackConfig()
    result = attack(heatmaps[flavour], panda, objects, q, goal, 5, method, cfg, seed=3)
    assert result.status == AttackStatus.SUCCESS, result.message
    assert len(result.obstacles) == 5 == len(result.masses)
    assert [o.id for o in result.obstacles] == [f'adv_{i}' for i in range(5)]
    assert result.total_mass == pytest.approx(sum(result.masses))
    assert all(m >= 0 for m in result.masses)
    _assert_constraints(result, panda, heatmaps[flavour], objects, q, goal, cfg)


def test_greedy_first_box_is_the_best_valid_candidate(panda, heatmaps, task):
    q, goal, objects = task
    region = search_region(heatmaps['scene'], panda, objects, q, goal)
    cands = np.argwhere(region.candidates)
    assert len(cands) > 100
    masses = np.array([_cube_mass(region.weights, c, region.k) for c in cands])
    best = next(m for m, c in sorted(zip(-masses, map(tuple, cands))) if region.accept(
        np.array(c)))
    result = attack(heatmaps['scene'], panda, objects, q, goal, 1, 'ours')
    assert result.masses[0] == pytest.approx(-best, rel=1e-12)


def test_greedy_beats_random_and_is_deterministic(panda, heatmaps, task):
    q, goal, objects = task
    hm = heatmaps['scene']
    ours = [attack(hm, panda, objects, q, goal, 3, 'ours', seed=s) for s in (0, 1)]
    assert ours[0].obstacles == ours[1].obstacles and ours[0].masses == ours[1].masses
    rnd = [attack(hm, panda, objects, q, goal, 3, 'random', seed=s) for s in (5, 5, 6)]
    assert rnd[0].obstacles == rnd[1].obstacles
    assert rnd[0].obstacles != rnd[2].obstacles
    assert ours[0].total_mass > max(r.total_mass for r in rnd)


def test_partial_when_few_candidates_fit(panda, heatmaps, task):
    q, goal, objects = task
    cfg = AttackConfig(corridor_radius_m=0.12, d_min_m=0.15, max_budget=100)
    result = attack(heatmaps['scene'], panda, objects, q, goal, 50, 'ours', cfg)
    assert result.status == AttackStatus.PARTIAL
    assert 0 < len(result.obstacles) < 50
    assert 'of 50 boxes' in result.message
    _assert_constraints(result, panda, heatmaps['scene'], objects, q, goal, cfg)


def test_robot_only_heatmap_masks_the_current_scene(panda, heatmaps, task):
    q, goal, objects = task
    hm = heatmaps['robot_only']
    assert hm.robot_only and hm.free.all()
    first = attack(hm, panda, (), q, goal, 1, 'ours')
    assert first.status == AttackStatus.SUCCESS
    # Put a scene object where the first box went: the attack must now avoid it.
    blocker = make_box('blocker', first.centers_m[0], (0.08, 0.08, 0.08))
    region = search_region(hm, panda, (blocker,), q, goal)
    centre_idx = hm.grid.index_of(first.centers_m[0]) - region.lo
    assert region.weights[tuple(centre_idx)] == 0
    assert not region.candidates[tuple(centre_idx)]
    again = attack(hm, panda, (blocker,), q, goal, 3, 'ours')
    assert again.status == AttackStatus.SUCCESS
    _assert_constraints(again, panda, hm, (blocker,), q, goal, AttackConfig())


def test_goal_hand_is_kept_clear(panda, heatmaps, task):
    q, goal, objects = task
    result = attack(heatmaps['scene'], panda, objects, q, goal, 5,
                    cfg=AttackConfig(protect_goal_hand=True))
    assert result.stats['goal_ik'] is True
    q_goal = np.array(result.stats['q_goal'])
    world = CollisionWorld(panda)
    placements = world.link_placements(q_goal)
    joint = panda.model.frames[panda.ee_frame].parentJoint
    for obj in result.obstacles:
        for g, T in zip(world.geom_model.geometryObjects, placements):
            if g.parentJoint == joint:
                assert _distance(obj.shapes[0], obj.shapes[0].pose.to_se3(), g.geometry,
                                 pin.SE3(T)) >= 0.1 - 1e-3  # q_goal rounded to 1e-4 rad


@pytest.mark.parametrize('change,status', [
    (dict(budget=0), AttackStatus.INVALID_REQUEST),
    (dict(budget=101), AttackStatus.INVALID_REQUEST),
    (dict(method='pfa'), AttackStatus.UNKNOWN_METHOD),
    (dict(box_size_m=float('nan')), AttackStatus.INVALID_REQUEST),
    (dict(box_size_m=-0.1), AttackStatus.INVALID_REQUEST),
    (dict(q=np.full(7, np.inf)), AttackStatus.INVALID_START),
    (dict(q=np.zeros(6)), AttackStatus.INVALID_START),
    (dict(q=np.full(7, 3.5)), AttackStatus.INVALID_START),
    (dict(q='collide'), AttackStatus.START_IN_COLLISION),
    (dict(goal='empty'), AttackStatus.INVALID_GOAL),
    (dict(goal='link'), AttackStatus.INVALID_LINK),
])
def test_bad_requests_get_a_status_not_an_exception(panda, heatmaps, task, change, status):
    q, goal, objects = task
    args = dict(budget=3, method='ours', box_size_m=None, q=q, goal=goal)
    args.update(change)
    if isinstance(args['q'], str):  # a box around the hand at q_init
        objects = objects + (make_box('on_hand', panda.ee_pose(q).translation, (0.1,) * 3),)
        args['q'] = q
    if args['goal'] == 'empty':
        args['goal'] = GoalRegion(goal.center, (0, 0, 0), (0, 0, 0))
    elif args['goal'] == 'link':
        args['goal'] = dataclasses.replace(goal, link='no_such_link')
    result = attack(heatmaps['scene'], panda, objects, args['q'], args['goal'], args['budget'],
                    args['method'], box_size_m=args['box_size_m'])
    assert result.status == status, result.message
    assert result.message and not result.obstacles


def test_heatmap_of_another_robot_is_refused(panda, heatmaps, task):
    q, goal, objects = task
    hm = dataclasses.replace(heatmaps['scene'], meta={**heatmaps['scene'].meta,
                                                      'robot_hash': 'ffff'})
    assert attack(hm, panda, objects, q, goal, 1).status == AttackStatus.ROBOT_MISMATCH


@pytest.mark.parametrize('extra, words', [
    (('table', (0.0, 0.8, 0.3)), "object ids repeat: ['table']"),
    (('adv_2', (0.0, 0.8, 0.3)), "object ids ['adv_2'] are the names of the attack's boxes")])
def test_ambiguous_object_ids_are_refused(panda, heatmaps, task, extra, words):
    """MoveIt replaces an object on ADD with its id: a repeated id, or one of the boxes' own,
    would make the attacked scene (and its witness check) ambiguous."""
    q, goal, objects = task
    assert 'table' in [o.id for o in objects]
    objects = objects + (make_box(extra[0], extra[1], (0.05,) * 3),)
    result = attack(heatmaps['scene'], panda, objects, q, goal, 1)
    assert result.status == AttackStatus.INVALID_REQUEST and words in result.message
    assert not result.obstacles


def test_obstacles_file_round_trip(panda, heatmaps, task, tmp_path):
    q, goal, objects = task
    result = attack(heatmaps['scene'], panda, objects, q, goal, 3, 'ours', box_size_m=0.06)
    path = tmp_path / 'sub' / 'obstacles.yaml'
    save_obstacles(path, obstacles_data(result, heatmaps['scene'], 'table_pick', 'abc'))
    loaded, meta = load_obstacles(path)
    assert loaded == result.obstacles
    assert objects_from_data(read_yaml(path)['objects'], 'objects') == result.obstacles
    assert meta['method'] == 'ours' and meta['budget'] == 3 and meta['box_size_m'] == 0.06
    assert meta['masses'] == pytest.approx(list(result.masses))
    assert meta['heatmap']['robot_hash'] == panda.hash
    assert list(tmp_path.joinpath('sub').iterdir()) == [path]  # no temp file left behind


def test_pose_of_obstacles_is_axis_aligned():
    obj = make_box('adv_0', (0.1, 0.2, 0.3), (0.05,) * 3)
    assert obj.shapes[0].pose == Pose((0.1, 0.2, 0.3))


def test_cli_attack_writes_the_obstacles_file(heatmaps, tmp_path, capsys):
    import json

    from advocc_ros.cli import main
    from advocc_ros.heatmap import save_heatmap
    save_heatmap(heatmaps['scene'], tmp_path / 'h.npz')
    out = tmp_path / 'obstacles.yaml'
    args = ['attack', '--heatmap', str(tmp_path / 'h.npz'), '--scene', 'table_pick',
            '--budget', '3', '--out', str(out), '--json']
    assert main(args) == 0
    printed = json.loads(capsys.readouterr().out)
    objects, meta = load_obstacles(out)
    assert [o['id'] for o in printed['obstacles']] == [o.id for o in objects] == \
        ['adv_0', 'adv_1', 'adv_2']
    assert printed['compute_ms'] > 0 and meta['compute_ms'] == printed['compute_ms']
    assert main(args[:-1] + ['--method', 'pfa', '--queries', '1']) == 2  # < baseline + 1
    assert main(['attack', '--heatmap', str(tmp_path / 'missing.npz'), '--scene', 'table_pick',
                 '--budget', '3', '--out', str(out)]) == 2
    assert 'cannot read' in capsys.readouterr().err
