"""The parts of method ``task``: approach samples, the tier weights, the goal filter, the
goal guard of the ``reachable`` policy and the ``solvable`` policy's grown witness mask."""

import numpy as np
import pytest
from scipy import ndimage, sparse

from advocc_ros.attack.goals import GoalSamples
from advocc_ros.attack.objective import WEIGHT_FLOOR, goal_filter, lexicographic_weights
from advocc_ros.attack.policy import GoalGuard, grown_by_a_voxel
from advocc_ros.attack.task import approach_samples
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.goal_batch import planner_goals
from advocc_ros.kinematics.ik import start_configuration


@pytest.fixture(scope='module')
def table(table_scene, panda):
    world = CollisionWorld(panda, table_scene.shapes)
    q_init = start_configuration(table_scene, panda)
    Q_goal = planner_goals(panda, table_scene.goal, world.collisions_batch, 8, seed=3).Q
    assert len(Q_goal) == 8
    return world, q_init, Q_goal


def test_straight_approaches_are_the_final_half_of_each_segment(table):
    world, q_init, Q_goal = table
    Q = approach_samples(world, q_init, Q_goal, 4, 0, 0.4, np.random.default_rng(0))
    assert 0 < len(Q) <= 4 * len(Q_goal)
    for q in Q:  # q = q_init + t (g - q_init) for one goal g and t in {0.5, 0.625, 0.75, 0.875}
        fits = []
        for g in Q_goal:
            t = np.dot(q - q_init, g - q_init) / np.dot(g - q_init, g - q_init)
            if np.allclose(q, q_init + t * (g - q_init), atol=1e-12):
                fits.append(t)
        assert any(np.isclose(t, [0.5, 0.625, 0.75, 0.875]).any() for t in fits), fits
    assert not world.collisions_batch(Q).any()
    assert np.all((Q >= world.robot.lower) & (Q <= world.robot.upper))


def test_detours_without_spread_repeat_the_straight_path_and_spread_moves_them(table):
    world, q_init, Q_goal = table
    straight = approach_samples(world, q_init, Q_goal, 3, 0, 0.0, np.random.default_rng(0))
    same = approach_samples(world, q_init, Q_goal, 3, 2, 0.0, np.random.default_rng(0))
    np.testing.assert_allclose(same, np.concatenate([straight] * 3))
    spread = approach_samples(world, q_init, Q_goal, 3, 2, 0.4, np.random.default_rng(0))
    assert len(spread) > len(straight)
    assert not world.collisions_batch(spread).any()
    assert np.all((spread >= world.robot.lower) & (spread <= world.robot.upper))
    off = [q for q in spread if not np.any(np.all(np.isclose(straight, q), axis=1))]
    assert off  # detours leave the straight segments


def test_no_goals_or_no_points_give_no_approaches(table):
    world, q_init, Q_goal = table
    rng = np.random.default_rng(0)
    assert approach_samples(world, q_init, Q_goal[:0], 4, 2, 0.4, rng).shape == (0, 7)
    assert approach_samples(world, q_init, Q_goal, 0, 2, 0.4, rng).shape == (0, 7)


@pytest.mark.parametrize('seed', range(20))
def test_tier_weights_rank_exits_then_goal_then_deep_then_approach(seed):
    rng = np.random.default_rng(seed)
    w_exit = np.ones(rng.integers(0, 50))
    w_goal = rng.uniform(WEIGHT_FLOOR, 1.0, rng.integers(1, 80))
    w_app = rng.uniform(0.0, 1.0, rng.integers(0, 700))
    weights = lexicographic_weights(w_exit, w_goal, w_goal, w_app)
    e, n = len(w_exit), len(w_goal)
    exits, goal, deep, app = weights[:e], weights[e:e + n], weights[e + n:e + 2 * n], \
        weights[e + 2 * n:]
    np.testing.assert_array_equal(app, w_app)
    assert deep.min() > app.sum()              # one deep row beats every approach
    assert goal.min() > deep.sum() + app.sum()  # one goal row beats everything below it
    assert exits.min(initial=np.inf) > goal.sum() + deep.sum() + app.sum()
    # within a tier the order of w(q) is kept
    assert np.all(np.argsort(goal, kind='stable') == np.argsort(w_goal, kind='stable'))


def _guard(table, min_fraction):
    world, _, Q_goal = table
    return GoalGuard(GoalSamples(world, Q_goal), 0.05, min_fraction)


def _hand_center(table, k):
    world, _, Q_goal = table
    return np.asarray(world.robot.ee_pose(Q_goal[k]).translation)


def test_goal_guard_commits_only_the_boxes_it_admits(table):
    guard = _guard(table, 1.0)
    box = _hand_center(table, 0)  # on sample 0's hand: blocks it
    assert guard.samples.blocked_by(box, 0.05)[0]
    assert not guard.admit(box)
    assert guard.valid.all()  # the refused box left no trace
    assert guard.admit(np.array([0.0, 0.9, 1.5]))  # far from every sample
    assert guard.valid.all()
    lenient = _guard(table, 0.0)
    assert lenient.admit(box)
    np.testing.assert_array_equal(lenient.valid, ~lenient.samples.blocked_by(box, 0.05))


def test_goal_filter_follows_the_guard_valid_samples(table):
    guard = _guard(table, 0.5)
    n = len(guard.valid)
    cover = np.zeros((n, 3), dtype=bool)
    cover[:5, 0] = True      # blocks 5 of 8: leaves 3/8 < 0.5
    cover[:4, 1] = True      # blocks 4 of 8: leaves exactly 0.5
    feasible = goal_filter(guard, sparse.csr_matrix(cover))
    np.testing.assert_array_equal(feasible(), [False, True, True])
    guard.valid[6:] = False  # two samples already blocked by earlier boxes
    np.testing.assert_array_equal(feasible(), [False, False, True])
    guard.valid[:] = True
    cover[:, 2] = True       # a box over every sample
    np.testing.assert_array_equal(goal_filter(guard, sparse.csr_matrix(cover))(),
                                  [False, True, False])


def test_detour_paths_pass_through_their_perturbed_midpoint(table):
    """With one point per path (t = 0.5) a detour sample is the perturbed midpoint of
    q_init and its goal, not a point near the goal."""
    world, q_init, Q_goal = table
    Q = approach_samples(world, q_init, Q_goal, 1, 1, 0.05, np.random.default_rng(1))
    mids = (q_init + Q_goal) / 2
    assert np.linalg.norm(Q_goal - q_init, axis=1).min() > 0.6  # midpoints are far from goals
    assert len(Q) > len(Q_goal)
    for q in Q:
        assert np.linalg.norm(mids - q, axis=1).min() < 0.3


def test_exit_rays_join_numbers_the_rays_after():
    """``ExitRays.join``: the rays of ``more`` numbered after these, their states after."""
    from advocc_ros.attack.exits import ExitRays

    rays = ExitRays(np.zeros((5, 7)), np.array([0, 0, 0, 1, 1]))
    both = rays.join(ExitRays(np.ones((2, 7)), np.array([0, 0])))
    assert both.count == 3 and list(both.ray) == [0, 0, 0, 1, 1, 2, 2]
    assert both.states[5:].all() and not both.states[:5].any()
    assert ExitRays(np.zeros((0, 7)), np.zeros(0, dtype=int)).count == 0


def test_exits_are_placed_for_after_a_draw_finds_some_and_counted_again_after_none():
    """``close_exits`` on scripted counts: placement a leaves 3 exits on draw 0, so b is placed
    to close them; b leaves none on draw 1, so b is counted again on draw 2 (2 left), and c is
    placed for all 5 found; c leaves 1 on draw 3. b and c both leave 1 a draw: b, the
    earlier, is kept."""
    from advocc_ros.attack.exits import ExitRays, close_exits

    class Scripted:
        ends = np.zeros((0, 2))
        counts = {('a', 0): 3, ('b', 1): 0, ('b', 2): 2, ('c', 3): 1}

        def free_ends(self, boxes, draw=0):
            return np.ones((self.counts[(boxes, draw)], 2))

        def rays_to(self, ends):
            return ExitRays(np.zeros((len(ends), 2)), np.arange(len(ends)))

    closing, made = [], iter('bc')

    def place(rays):
        closing.append(rays.count)
        return next(made)
    kept, stats = close_exits(Scripted(), 'a', np.ones((3, 2)), place, lambda p: p, 3)
    assert kept == 'b' and closing == [3, 5]
    assert stats == {'goal_exits_by_round': [3, 0, 2, 1], 'goal_exits': 2,
                     'goal_exit_draws_kept': [1, 2]}
    assert close_exits(Scripted(), 'a', np.ones((3, 2)), place, lambda p: p, 0)[1] == {
        'goal_exits_by_round': [3], 'goal_exits': 3, 'goal_exit_draws_kept': [0]}


@pytest.mark.parametrize('shape', [(1, 1, 1), (3, 1, 4), (9, 10, 11)])
def test_the_witness_mask_grows_by_the_face_neighbours_as_scipys_dilation(shape):
    rng = np.random.default_rng(len(shape) + shape[0])
    for density in (0.0, 0.02, 0.3, 1.0):
        mask = rng.random(shape) < density
        grown = grown_by_a_voxel(mask)
        assert grown.dtype == bool and (grown == ndimage.binary_dilation(mask)).all()
    one = np.zeros((3, 3, 3), bool)
    one[1, 1, 1] = True
    assert grown_by_a_voxel(one).sum() == 7 and one.sum() == 1  # its input is left as it was
