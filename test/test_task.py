"""Method ``task``: greedy against brute force, the coverage kernel against a direct
rasterization, constraints, nesting, goal policies, and its effect on a real planner."""

import itertools

import numpy as np
import pytest

from advocc_ros.attack import AttackConfig, AttackStatus, attack, robot_occupancy, search_region
from advocc_ros.attack.configurations import cover_matrix, touching_mask
from advocc_ros.attack.greedy import greedy_configurations
from advocc_ros.attack.goals import goal_samples
from advocc_ros.evaluation.runner import evaluate_planner
from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import planner_goals
from advocc_ros.planning.types import PlanningConfig

from test_attack import _assert_constraints

# ---------------------------------------------------------------------------------------------
# Greedy over configurations: brute force is computable on small instances


def _instance(seed, n_configs=9, n_cand=8):
    rng = np.random.default_rng(seed)
    cover = rng.random((n_configs, n_cand)) < 0.3
    weights = rng.gamma(1.0, 1.0, n_configs)
    centers = rng.uniform(0, 0.2, (n_cand, 3))
    return cover, weights, centers


def _value(cover, weights, picks):
    return float(weights[np.any(cover[:, list(picks)], axis=1)].sum()) if picks else 0.0


def _best(cover, weights, centers, budget, d_min):
    best = 0.0
    for m in range(1, budget + 1):
        for combo in itertools.combinations(range(cover.shape[1]), m):
            if all(np.linalg.norm(centers[a] - centers[b]) >= d_min
                   for a, b in itertools.combinations(combo, 2)):
                best = max(best, _value(cover, weights, combo))
    return best


@pytest.mark.parametrize('seed', range(5))
def test_one_box_is_the_best_box(seed):
    cover, weights, centers = _instance(seed)
    picks, _ = greedy_configurations(cover, weights, centers, 1, 0.0)
    assert _value(cover, weights, picks) == pytest.approx(_best(cover, weights, centers, 1, 0))


@pytest.mark.parametrize('seed,budget', [(s, m) for s in range(6) for m in (2, 3)])
def test_greedy_keeps_d_min(seed, budget):
    """Separation of the picks; the guarantee is tested in test_greedy_guarantee.py."""
    cover, weights, centers = _instance(50 + seed)
    d_min = 0.05
    picks, _ = greedy_configurations(cover, weights, centers, budget, d_min)
    assert picks
    for a, b in itertools.combinations(picks, 2):
        assert np.linalg.norm(centers[a] - centers[b]) >= d_min


def test_greedy_stops_when_nothing_is_left_and_honours_filters():
    cover = np.zeros((3, 4), dtype=bool)
    cover[0, 1] = cover[1, 1] = cover[2, 3] = True
    weights = np.ones(3)
    centers = np.arange(12, dtype=float).reshape(4, 3)
    picks, _ = greedy_configurations(cover, weights, centers, 4, 0.0)
    assert picks == [1, 3]  # a third box would cover nothing: not placed
    picks, rejected = greedy_configurations(cover, weights, centers, 4, 0.0,
                                            accept=lambda j: j != 1)
    assert picks == [3] and rejected == 1
    picks, _ = greedy_configurations(cover, weights, centers, 4, 0.0,
                                     feasible=lambda: np.array([True, False, True, True]))
    assert picks == [3]


# ---------------------------------------------------------------------------------------------
# The Panda task (table_pick): real heatmap, real IK, exact coal checks


@pytest.fixture(scope='module')
def heatmap(table_scene):
    return build_heatmap(table_scene, HeatmapConfig(samples=2000), seed=1)


@pytest.fixture(scope='module')
def task(panda, table_scene):
    q = panda.q_from_names(list(table_scene.start), list(table_scene.start.values()))
    return q, table_scene.goal, table_scene.objects


def test_cover_matrix_matches_a_direct_rasterization(panda, heatmap, task):
    q, goal, objects = task
    region = search_region(heatmap, panda, objects, q, goal)
    world = CollisionWorld(panda, [s for o in objects for s in o.shapes])
    Q = planner_goals(panda, goal, world.collisions_batch, 4, seed=2).Q
    assert len(Q) == 4
    cover = cover_matrix(panda, world, Q, region).toarray().astype(bool)
    cand = np.argwhere(region.candidates)
    k = region.k
    for row, qs in zip(cover, Q):
        occ = robot_occupancy(panda, world.link_placements(qs), region.grid, region.lo,
                              region.hi, region.lut_pitch_m)
        padded = np.pad(occ, k)
        expected = np.array([padded[c[0]:c[0] + 2 * k + 1, c[1]:c[1] + 2 * k + 1,
                                    c[2]:c[2] + 2 * k + 1].any() for c in cand])
        # The kernel and numpy round voxel centres into the link tables the same way; allow
        # a handful of boundary voxels where float rounding differs.
        assert np.sum(row != expected) <= max(3, 0.002 * len(cand))
        assert row.sum() > 0


def test_touching_mask_is_the_union_of_the_cover_rows(panda, heatmap, task):
    """The union kernel (fills each voxel once over all configurations) marks exactly the
    candidates that cover some configuration: the witness guard's prune relies on it."""
    q, goal, objects = task
    region = search_region(heatmap, panda, objects, q, goal)
    world = CollisionWorld(panda, [s for o in objects for s in o.shapes])
    Q = planner_goals(panda, goal, world.collisions_batch, 24, seed=3).Q
    Q = np.concatenate([Q, np.linspace(q, Q[0], 16)])  # overlapping bodies along a path
    cover = cover_matrix(panda, world, Q, region)
    expected = np.zeros(region.candidates.shape, dtype=bool)
    expected[tuple(np.argwhere(region.candidates)[np.diff(cover.tocsc().indptr) > 0].T)] = True
    mask = touching_mask(panda, world, Q, region)
    assert expected.any() and not expected.all()
    assert np.array_equal(mask, expected)
    assert not touching_mask(panda, world, Q[:0], region).any()


def test_a_ray_row_is_covered_when_one_of_its_states_is(panda, heatmap, task):
    """``cover_matrix(..., rays=)``: one row a ray, the or of its states' rows (the kernel
    skips a voxel another state of the same ray filled, so overlapping states cost less)."""
    q, goal, objects = task
    region = search_region(heatmap, panda, objects, q, goal)
    world = CollisionWorld(panda, [s for o in objects for s in o.shapes])
    Q = planner_goals(panda, goal, world.collisions_batch, 3, seed=4).Q
    Q = np.concatenate([np.linspace(q, g, 12) for g in Q])  # three rays of overlapping states
    rays = np.repeat(np.arange(3), 12)
    states = cover_matrix(panda, world, Q, region).toarray().astype(bool)
    cut = cover_matrix(panda, world, Q, region, rays=rays).toarray().astype(bool)
    assert cut.shape == (3, states.shape[1])
    expected = np.array([states[rays == r].any(axis=0) for r in range(3)])
    assert np.array_equal(cut, expected) and expected.any()
    assert cover_matrix(panda, world, Q[:0], region, rays=rays[:0]).shape == (0, cut.shape[1])


def test_task_respects_every_constraint_and_is_nested(panda, heatmap, task):
    q, goal, objects = task
    cfg = AttackConfig()
    five = attack(heatmap, panda, objects, q, goal, 5, 'task', cfg, seed=4)
    assert five.status.ok, five.message
    assert 1 <= len(five.obstacles) <= 5 and len(five.masses) == len(five.obstacles)
    _assert_constraints(five, panda, heatmap, objects, q, goal, cfg)
    three = attack(heatmap, panda, objects, q, goal, 3, 'task', cfg, seed=4)
    n = min(3, len(five.obstacles))
    assert np.allclose(three.centers_m[:n], five.centers_m[:n])  # prefixes: `advocc audit`
    again = attack(heatmap, panda, objects, q, goal, 5, 'task', cfg, seed=4)
    assert np.array_equal(again.centers_m, five.centers_m)
    assert five.stats['task_goal_samples'] > 0 and five.stats['task_approach_samples'] > 0


def test_goal_valid_fraction_is_exact(panda, heatmap, task):
    q, goal, objects = task
    result = attack(heatmap, panda, objects, q, goal, 2, 'ours', seed=0)
    samples = goal_samples(panda, objects, goal)
    world = CollisionWorld(panda, [s for o in (*objects, *result.obstacles) for s in o.shapes])
    still = ~world.collisions_batch(samples.Q)
    assert result.goal_valid_fraction == pytest.approx(still.mean())


def test_task_blocks_the_goal_under_paper_and_spares_it_under_reachable(panda, heatmap, task):
    q, goal, objects = task
    paper = attack(heatmap, panda, objects, q, goal, 3, 'task', seed=0)
    ours = attack(heatmap, panda, objects, q, goal, 3, 'ours', seed=0)
    assert paper.goal_policy == 'paper'
    assert paper.goal_valid_fraction < 0.5
    assert paper.goal_valid_fraction <= ours.goal_valid_fraction
    cfg = AttackConfig(reachable_fraction=0.6)
    reach = attack(heatmap, panda, objects, q, goal, 3, 'task', cfg, seed=0,
                   goal_policy='reachable')
    assert reach.status.ok and reach.goal_policy == 'reachable'
    assert reach.goal_valid_fraction >= 0.6
    for method in ('ours', 'random'):  # the policy binds every coverage method
        other = attack(heatmap, panda, objects, q, goal, 5, method, cfg, seed=0,
                       goal_policy='reachable')
        assert other.goal_valid_fraction >= 0.6


def test_the_objective_has_goal_rows_only_where_the_goal_set_is_a_target(panda, heatmap, task):
    """Under ``paper`` the rows are the goal tier, its deep copy and the passage; under
    ``reachable`` the goal set is no target, so no goal row is built, only the passage (and the
    goal guard's filter)."""
    from advocc_ros.attack.methods import MethodContext
    from advocc_ros.attack.objective import task_objective
    from advocc_ros.attack.policy import apply_policy
    from advocc_ros.attack.task import TaskOptions, task_sample
    from advocc_ros.attack.types import Task

    q, goal, objects = task
    region = search_region(heatmap, panda, objects, q, goal)
    for policy in ('paper', 'reachable'):
        t = Task(panda, tuple(objects), q, goal, policy)
        sample = task_sample(t, TaskOptions(), seed=0)
        policed = apply_policy(t, region, AttackConfig(), (), sample.goals)
        objective = task_objective(MethodContext.of(t, None, sample, policed), policed.region)
        n_goal, n_path = len(sample.goals), len(sample.approaches)
        assert n_goal > 0 and objective.passage_rows == n_path > 0
        if policy == 'paper':
            assert objective.goal_rows == n_goal and objective.feasible is None
            assert objective.cover.shape[0] == 2 * n_goal + n_path
        else:
            assert objective.goal_rows == 0 and objective.feasible is not None
            assert objective.cover.shape[0] == n_path
            np.testing.assert_array_equal(objective.weights, objective.reported)
        assert objective.cover.shape[1] == policed.region.candidates.sum()


def test_the_task_names_its_policy_and_goal_form(panda, task):
    """The goal form is the goal's own (one source), and an unknown one is refused there."""
    import dataclasses

    from advocc_ros.attack.types import Task
    from advocc_ros.model.goal import GOAL_FORMS

    q, goal, objects = task
    assert Task(panda, tuple(objects), q, goal).goal_form == GOAL_FORMS[0] == 'region'
    with pytest.raises(ValueError, match='goal policy'):
        Task(panda, tuple(objects), q, goal, 'maybe')
    with pytest.raises(ValueError, match='goal.form'):
        dataclasses.replace(goal, form='somewhere')


def test_bad_policy_and_pfa_under_reachable_are_clear_errors(panda, heatmap, task):
    q, goal, objects = task
    bad = attack(heatmap, panda, objects, q, goal, 1, 'task', goal_policy='nope')
    assert bad.status == AttackStatus.INVALID_REQUEST and 'goal policy' in bad.message
    pfa = attack(heatmap, panda, objects, q, goal, 1, 'pfa', goal_policy='reachable')
    assert pfa.status == AttackStatus.INVALID_REQUEST and 'reachable' in pfa.message
    with pytest.raises(ValueError, match='goal_policy'):
        AttackConfig(goal_policy='maybe')


@pytest.mark.processes
def test_task_makes_a_real_planner_fail(panda, heatmap, task, table_scene):
    q, goal, objects = task
    result = attack(heatmap, panda, objects, q, goal, 3, 'task', seed=0)
    config = PlanningConfig()
    attacked = evaluate_planner(table_scene.with_objects(result.obstacles), 'rrtconnect', 3,
                                5.0, seed=0, planning_config=config)
    clean = evaluate_planner(table_scene, 'rrtconnect', 3, 5.0, seed=0, planning_config=config)
    assert clean['psr'] >= 2 / 3  # unattacked RRTConnect solves table_pick in ~0.3 s
    assert attacked['psr'] <= 1 / 3
    assert attacked['failures']['goal not sampled'] + attacked['failures']['timed out'] > 0
