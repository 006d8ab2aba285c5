"""Method ``task`` under ``solvable``: the best of several draws, chosen without a planner."""

import numpy as np
import pytest

from advocc_ros.attack import attack
from advocc_ros.attack.goals import selection_goal_samples
from advocc_ros.attack.judge import judge, kept_index
from advocc_ros.attack.solvable import witness_bodies
from advocc_ros.attack.task import TaskOptions, draw_seed, passage_samples
from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.model.collision import shared_world
from advocc_ros.model.robot import load_robot
from advocc_ros.planning.witness import find_witness
from conftest import JUDGE

pytestmark = pytest.mark.processes  # the witness search starts a planning worker


@pytest.fixture(scope='module')
def task(table_scene):
    robot = load_robot(table_scene.robot)
    q0 = robot.q_from_names(list(table_scene.start), list(table_scene.start.values()), 'start')
    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=1500), seed=0)
    witness = find_witness(robot, table_scene.objects, q0, table_scene.goal)
    return table_scene, robot, q0, heatmap, witness


def _attack(task, draws: int, seed: int = 3, policy: str = 'solvable'):
    scene, robot, q0, heatmap, witness = task
    options = TaskOptions(draws=draws, selection_samples=JUDGE)
    return attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=seed,
                  goal_policy=policy, witness=witness, method_options=options)


def test_the_kept_draw_is_the_one_the_judge_keeps(task):
    scene, robot, _, _, witness = task
    best = _attack(task, draws=4)
    assert best.status.ok and best.solvable.certified, best.message
    goals = selection_goal_samples(robot, scene.objects, scene.goal, JUDGE)
    assert len(goals.Q) > 100
    bodies = witness_bodies(robot, shared_world(robot), witness)
    passage = passage_samples(robot, scene.objects, scene.goal, bodies.states, 4096)
    assert len(passage.Q) > 500
    # Each draw on its own: the attack with draws=1 and that draw's seed.
    singles = [_attack(task, draws=1, seed=draw_seed(3, k)) for k in range(4)]
    judged = [judge(goals, passage, r.centers_m, r.box_size_m) for r in singles]
    assert best.stats['task_draw_goal_valid'] == pytest.approx(
        [goals.valid_fraction(r.centers_m, r.box_size_m) for r in singles], abs=1e-6)
    assert best.stats['task_draw_passage_free'] == pytest.approx(
        [j.passage_free for j in judged], abs=1e-4)
    assert best.stats['task_selection_samples'] == len(goals.Q)
    kept = best.stats['task_draw_kept']
    assert kept == kept_index(judged)
    np.testing.assert_array_equal(best.centers_m, singles[kept].centers_m)
    assert best.solvable.certified and all(r.solvable.certified for r in singles)


def test_without_the_passage_the_fewest_goals_decide(task):
    scene, robot, q0, heatmap, witness = task
    options = TaskOptions(draws=4, selection_samples=JUDGE, passage_samples=0)
    result = attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=3,
                    goal_policy='solvable', witness=witness, method_options=options)
    valid = result.stats['task_draw_goal_valid']
    assert result.stats['task_draw_passage_free'] == [1.0] * 4
    assert result.stats['task_draw_kept'] == valid.index(min(valid))


def test_one_draw_is_the_attack_of_the_seed_itself(task):
    one = _attack(task, draws=1).stats
    assert one['task_draws'] == 1 and one['task_draw_kept'] == 0
    assert draw_seed(3, 0) == 3 and len({draw_seed(3, k) for k in range(8)}) == 8
    assert draw_seed(4, 1) != draw_seed(3, 1)  # another attack seed, other draws


def test_draws_apply_under_solvable_only(task):
    paper = _attack(task, draws=4, policy='paper')
    assert 'task_draws' not in paper.stats  # paper and reachable keep nested picks
    single = _attack(task, draws=1, policy='paper')
    np.testing.assert_array_equal(paper.centers_m, single.centers_m)


@pytest.mark.parametrize('bad', [0, -1, 2.5, True])
def test_options_refuse_a_bad_number_of_draws(bad):
    with pytest.raises(ValueError, match='draws'):
        TaskOptions(draws=bad)
