"""Method ``task`` under ``solvable`` with witnesses to rare goal configurations: the ends are
found without a planner, their witnesses are certified paths to them, and the attack keeps the
witness whose boxes leave the fewest selection goal samples valid."""

import numpy as np
import pytest

from advocc_ros.attack import attack
from advocc_ros.attack.edges import attack_task, task_witness, witness_plan
from advocc_ros.attack.goals import (END_SAMPLES, RARITY_NEIGHBOUR, rare_goal_configurations,
                                     selection_goal_samples)
from advocc_ros.attack.judge import Judged, judge, kept_index
from advocc_ros.attack.solvable import witness_bodies
from advocc_ros.attack.task import TaskOptions, passage_samples, task_options
from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.model.collision import CollisionWorld, shared_world
from advocc_ros.model.robot import load_robot
from advocc_ros.planning import end_witnesses
from advocc_ros.planning.witness import _tool_pose, certify
from conftest import JUDGE

pytestmark = pytest.mark.processes  # the witness searches start a planning worker


@pytest.fixture(scope='module')
def task(table_scene, tmp_path_factory):
    robot = load_robot(table_scene.robot)
    q0 = robot.q_from_names(list(table_scene.start), list(table_scene.start.values()), 'start')
    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=1500), seed=0)
    search = task_witness(robot, table_scene.objects, q0, table_scene.goal, ends=3)
    return table_scene, robot, q0, heatmap, search


def test_rare_ends_are_valid_goal_configurations_rarest_first(task):
    scene, robot, _, _, _ = task
    ends = rare_goal_configurations(robot, scene.objects, scene.goal, 4)
    assert ends.shape == (4, robot.nq)
    np.testing.assert_array_equal(ends, rare_goal_configurations(robot, scene.objects,
                                                                 scene.goal, 4))
    world = CollisionWorld(robot, scene.shapes)
    assert not world.collisions_batch(ends).any()
    data = robot.create_data()
    assert all(scene.goal.contains(_tool_pose(robot, data, q, scene.goal)) for q in ends)
    # Rarest first: the k-NN distances (over the whole end set) decrease along the list.
    everything = rare_goal_configurations(robot, scene.objects, scene.goal, END_SAMPLES)
    gaps = np.linalg.norm(everything[:, None] - everything[None], axis=-1)
    np.fill_diagonal(gaps, np.inf)
    rarity = np.sort(gaps, axis=1)[:, RARITY_NEIGHBOUR - 1]
    assert np.all(np.diff(rarity) <= 0) and rarity[0] > np.median(rarity)


def test_end_witnesses_are_certified_paths_to_their_ends(task):
    scene, robot, q0, _, search = task
    assert search.witness is not None and 1 <= len(search.ends) <= 3
    assert search.candidates[0] is search.witness
    ends = rare_goal_configurations(robot, scene.objects, scene.goal, 3)
    world = CollisionWorld(robot, scene.shapes)
    for witness in search.ends:
        Q = witness.configurations(robot)
        np.testing.assert_allclose(Q[0], q0, atol=1e-9)
        assert np.min(np.linalg.norm(ends - Q[-1], axis=1)) < 1e-6
        assert certify(robot, world, scene.goal, witness, q0).why is None


def test_an_end_whose_path_grazes_is_searched_with_the_next_seed(task):
    """table_pick's rarest end: the first seed's shortcut passes 0.0996 mm from the can, below
    the certificate's floor (measured); the next seed's path is proven, so no end is lost."""
    from advocc_ros.planning.witness import WITNESS_SEED

    *_, search = task
    assert [w.source['end'] for w in search.ends] == [0, 1, 2]
    assert search.ends[0].source['seed'] == WITNESS_SEED + 1


def test_end_witnesses_come_back_from_the_disk_cache(task, tmp_path, monkeypatch):
    scene, robot, q0, _, search = task
    monkeypatch.setenv('ADVOCC_WITNESS_CACHE', str(tmp_path))
    ends = rare_goal_configurations(robot, scene.objects, scene.goal, 3)
    end_witnesses._FOUND.clear()
    first = end_witnesses.find_end_witnesses(robot, scene.objects, q0, scene.goal, ends)
    assert len(list(tmp_path.glob('*.yaml'))) == 1
    end_witnesses._FOUND.clear()
    monkeypatch.setattr(end_witnesses, '_search', lambda *a: pytest.fail('searched again'))
    again = end_witnesses.find_end_witnesses(robot, scene.objects, q0, scene.goal, ends)
    assert [w.content_hash() for w in again] == [w.content_hash() for w in first]


def test_the_kept_witness_is_the_one_the_judge_keeps(task):
    scene, robot, q0, heatmap, search = task
    candidates = search.candidates
    best = attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=3,
                  goal_policy='solvable', witness=candidates,
                  method_options=TaskOptions(draws=1, end_draws=1, selection_samples=JUDGE))
    assert best.status.ok and best.solvable.certified, best.message
    # Each witness on its own: one draw each, the attack's seed.
    singles = [attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=3,
                      goal_policy='solvable', witness=w,
                      method_options=TaskOptions(draws=1, selection_samples=JUDGE))
               for w in candidates]
    goals = selection_goal_samples(robot, scene.objects, scene.goal, JUDGE)
    judged = [judge(goals, passage_samples(robot, scene.objects, scene.goal,
                                           witness_bodies(robot, shared_world(robot), w).states,
                                           TaskOptions().passage_samples),
                    r.centers_m, r.box_size_m) for w, r in zip(candidates, singles)]
    assert best.stats['task_witness_goal_valid'] == pytest.approx(
        [j.goal_fraction for j in judged], abs=1e-6)
    assert best.stats['task_witness_passage_free'] == pytest.approx(
        [j.passage_free for j in judged], abs=1e-4)
    kept = best.stats['task_witness_kept']
    assert kept == kept_index(judged)
    assert best.witness is candidates[kept]
    np.testing.assert_array_equal(best.centers_m, singles[kept].centers_m)
    assert best.stats['task_witnesses'] == len(candidates)
    assert best.stats['task_witness_draws'] == [1] * len(candidates)


def test_other_methods_and_policies_use_the_tasks_witness(task):
    scene, robot, q0, heatmap, search = task
    for method, policy in (('random', 'solvable'), ('task', 'paper')):
        result = attack(heatmap, robot, scene.objects, q0, scene.goal, 3, method, seed=1,
                        goal_policy=policy, witness=search.candidates)
        assert result.witness is search.witness and 'task_witnesses' not in result.stats
    assert witness_plan('random', 'solvable', None) == {'seeds': 1, 'ends': 0}
    assert witness_plan('task', 'paper', None) == {'seeds': 1, 'ends': 0}
    assert witness_plan('task', 'solvable', TaskOptions(witness_ends=2, witness_seeds=4,
                                                        selection_samples=300)) == \
        {'seeds': 4, 'ends': 2, 'judge_samples': 300}


def test_the_task_witness_draws_as_many_as_without_ends(task):
    """The task's witness keeps its draws beside the ends: with it kept, the attack is the
    one without ends; an end is kept only when the judge ranks its attack first."""
    scene, robot, q0, heatmap, search = task
    alone = attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=5,
                   goal_policy='solvable', witness=search.witness,
                   method_options=TaskOptions(draws=3, selection_samples=JUDGE))
    both = attack(heatmap, robot, scene.objects, q0, scene.goal, 6, 'task', seed=5,
                  goal_policy='solvable', witness=search.candidates,
                  method_options=TaskOptions(draws=3, end_draws=1, selection_samples=JUDGE))
    assert both.stats['task_witness_draws'] == [3] + [1] * len(search.ends)
    n = both.stats['task_selection_samples']
    judged = [Judged(round(g * n), n, p) for g, p in zip(
        both.stats['task_witness_goal_valid'], both.stats['task_witness_passage_free'])]
    assert both.stats['task_witness_kept'] == kept_index(judged)
    if both.stats['task_witness_kept'] == 0:
        np.testing.assert_array_equal(both.centers_m, alone.centers_m)


def test_the_edges_find_the_ends_and_the_attack_keeps_one(task):
    scene, robot, q0, heatmap, search = task
    result = attack_task(heatmap, robot, scene.objects, q0, scene.goal, 4, 'task', seed=0,
                         goal_policy='solvable', method_options=task_options(
                             {'draws': 2, 'witness_ends': 1, 'witness_seeds': 1}))
    assert result.status.ok and result.solvable.certified, result.message
    assert result.stats['task_witnesses'] == 2 and 'witness_search_ms' in result.stats
    assert result.witness in (search.witness, search.ends[0])


@pytest.mark.parametrize('option, bad', [('witness_ends', -1), ('witness_ends', 1.5),
                                         ('witness_ends', True), ('end_draws', 0)])
def test_options_refuse_bad_ends_and_end_draws(option, bad):
    with pytest.raises(ValueError, match=option):
        task_options({option: bad})


def test_more_searches_give_distinct_certified_witnesses_on_seeds_of_their_own(task):
    from advocc_ros.planning.witness import (WITNESS_SEED, WITNESS_SEED_STRIDE, WITNESS_TRIES,
                                             find_witness)

    scene, robot, q0, _, first = task
    search = task_witness(robot, scene.objects, q0, scene.goal, seeds=3)
    assert search.witness.content_hash() == first.witness.content_hash()
    assert search.witness.content_hash() == find_witness(
        robot, scene.objects, q0, scene.goal).content_hash()
    hashes = [w.content_hash() for w in (search.witness, *search.others)]
    assert len(hashes) == len(set(hashes)) == 3  # table_pick: three different straight lines
    world = CollisionWorld(robot, scene.shapes)
    for k, witness in enumerate((search.witness, *search.others)):
        own = WITNESS_SEED + k * WITNESS_SEED_STRIDE
        assert own <= witness.source['seed'] < own + WITNESS_TRIES
        assert certify(robot, world, scene.goal, witness, q0).why is None
    assert search.candidates == (search.witness, *search.others)
    assert WITNESS_SEED_STRIDE >= WITNESS_TRIES  # no search retries on another's seeds


def test_a_path_found_twice_is_one_candidate_and_no_path_ends_the_searches(monkeypatch, task):
    from advocc_ros.planning import witness as witness_module

    scene, robot, q0, _, search = task
    seeds = []

    def same_path(robot, objects, q_init, goal, seed):
        seeds.append(seed)
        return search.witness
    monkeypatch.setattr(witness_module, 'find_witness', same_path)
    assert witness_module.find_witnesses(robot, scene.objects, q0, scene.goal, 3) == \
        (search.witness,)
    assert len(seeds) == 3
    seeds.clear()
    monkeypatch.setattr(witness_module, 'find_witness',
                        lambda robot, objects, q_init, goal, seed: seeds.append(seed))
    assert witness_module.find_witnesses(robot, scene.objects, q0, scene.goal, 3) == ()
    assert len(seeds) == 1  # the first search found nothing: the others are not started


def test_the_attack_keeps_one_of_the_searches_witnesses(task):
    scene, robot, q0, heatmap, _ = task
    search = task_witness(robot, scene.objects, q0, scene.goal, seeds=2)
    result = attack_task(heatmap, robot, scene.objects, q0, scene.goal, 4, 'task', seed=0,
                         goal_policy='solvable', method_options=task_options(
                             {'draws': 1, 'witness_ends': 0, 'witness_seeds': 2,
                              'selection_samples': JUDGE}))
    assert result.status.ok and result.solvable.certified, result.message
    assert result.stats['task_witnesses'] == 2
    assert result.stats['task_witness_draws'] == [1, TaskOptions().end_draws]
    assert result.witness.content_hash() == \
        search.candidates[result.stats['task_witness_kept']].content_hash()


@pytest.mark.parametrize('bad', [0, 9, 1.5, True])
def test_options_refuse_bad_witness_seeds(bad):
    with pytest.raises(ValueError, match='witness_seeds'):
        task_options({'witness_seeds': bad})
