"""The goal sets that judge the task attack (selection and rare-end sets) on disk: read back
only when every configuration is still a valid goal of the task; never for ``perf attack``'s
cold timings."""

import logging

import numpy as np
import pytest

from advocc_ros.attack import goals
from advocc_ros.model.cache import clear_task_caches
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import make_box

N = 12
"""Goal configurations per set here (small: a few IK seconds at most)."""


@pytest.fixture
def task(table_scene, tmp_path, monkeypatch):
    monkeypatch.setenv('ADVOCC_WITNESS_CACHE', str(tmp_path))
    clear_task_caches()
    yield table_scene, load_robot(table_scene.robot), tmp_path
    clear_task_caches()


def _selection(scene, robot):
    return goals.selection_goal_samples(robot, scene.objects, scene.goal, N).Q


def _no_sampling(monkeypatch):
    monkeypatch.setattr(goals, '_sample_goals', lambda *a: pytest.fail('sampled again'))


def test_a_goal_set_comes_back_from_disk(task, monkeypatch):
    scene, robot, cache = task
    first = _selection(scene, robot)
    assert len(first) == N and len(list(cache.glob('*.goals.npz'))) == 1
    clear_task_caches()
    _no_sampling(monkeypatch)
    np.testing.assert_array_equal(_selection(scene, robot), first)


def test_the_rare_ends_come_back_from_disk(task, monkeypatch):
    scene, robot, cache = task
    monkeypatch.setattr(goals, 'END_SAMPLES', N)
    first = goals.rare_goal_configurations(robot, scene.objects, scene.goal, 3)
    clear_task_caches()
    _no_sampling(monkeypatch)
    again = goals.rare_goal_configurations(robot, scene.objects, scene.goal, 3)
    np.testing.assert_array_equal(again, first)


def _rewrite(cache, **arrays):
    (path,) = cache.glob('*.goals.npz')
    with open(path, 'wb') as handle:
        np.savez(handle, **arrays)


@pytest.mark.parametrize('damage', ['garbage', 'outside the region', 'nan', 'wrong width',
                                    'no array'])
def test_a_damaged_or_foreign_file_is_sampled_again(task, damage, caplog):
    scene, robot, cache = task
    first = _selection(scene, robot)
    clear_task_caches()
    Q = first.copy()
    if damage == 'garbage':
        next(cache.glob('*.goals.npz')).write_bytes(b'not an npz file')
    elif damage == 'outside the region':
        Q[3] = (robot.lower + robot.upper) / 2
        _rewrite(cache, Q=Q)
    elif damage == 'nan':
        Q[0, 0] = np.nan
        _rewrite(cache, Q=Q)
    elif damage == 'wrong width':
        _rewrite(cache, Q=Q[:, :-1])
    else:
        _rewrite(cache, other=Q)
    with caplog.at_level(logging.WARNING, logger=goals.__name__):
        again = _selection(scene, robot)
    np.testing.assert_array_equal(again, first)
    assert 'goal set cache' in caplog.text and 'sampling again' in caplog.text


def test_a_goal_that_now_collides_is_refused(task, caplog):
    scene, robot, cache = task
    first = _selection(scene, robot)
    (path,) = cache.glob('*.goals.npz')
    shapes = [sh for o in scene.objects for sh in o.shapes]
    world = CollisionWorld(robot, shapes)
    assert goals._read_goals(path, world, scene.goal, N) is not None
    hand_m = world.link_placements(first[0])[-1].translation
    blocked = CollisionWorld(robot, shapes + list(make_box('b', hand_m, (0.05,) * 3).shapes))
    assert blocked.in_collision(first[0])
    with caplog.at_level(logging.WARNING, logger=goals.__name__):
        assert goals._read_goals(path, blocked, scene.goal, N) is None
    assert 'does not hold valid goal configurations' in caplog.text


def test_cold_timings_neither_read_nor_write_the_disk(task, monkeypatch):
    scene, robot, cache = task
    with goals.sampled_afresh():
        first = _selection(scene, robot)
    assert not list(cache.iterdir())
    _selection(scene, robot)  # memory cache: still nothing written
    clear_task_caches()
    _selection(scene, robot)
    assert len(list(cache.glob('*.goals.npz'))) == 1
    clear_task_caches()
    calls = []
    monkeypatch.setattr(goals, '_sample_goals',
                        lambda *a: calls.append(1) or first)
    with goals.sampled_afresh():
        _selection(scene, robot)
    assert calls == [1]  # sampled although the file is there


def test_cache_off_writes_nothing(task, monkeypatch):
    scene, robot, cache = task
    monkeypatch.setenv('ADVOCC_WITNESS_CACHE', 'off')
    _selection(scene, robot)
    assert not list(cache.iterdir())
