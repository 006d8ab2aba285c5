"""Batched kinematics against pinocchio, and the planner-like goal sample drawn with it."""

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.kinematics.batch import ChainKinematics, dls
from advocc_ros.kinematics.goal_batch import (GoalSampler, planner_goals, rarest_first,
                                              task_goals)
from advocc_ros.model.collision import CollisionWorld


@pytest.fixture(scope='module')
def chain(panda, table_scene):
    return ChainKinematics(panda.model, panda.model.getFrameId(table_scene.goal.link))


def test_compiled_frames_match_pinocchio(panda, table_scene, chain):
    model, data = panda.model, panda.create_data()
    fid = model.getFrameId(table_scene.goal.link)
    Q = np.random.default_rng(0).uniform(panda.lower, panda.upper, (40, panda.nq))
    T = chain.frame(Q)
    assert chain.supports and T.shape == (40, 4, 4) and chain.frame(Q[:0]).shape == (0, 4, 4)
    for i, q in enumerate(Q):
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(T[i], data.oMf[fid].homogeneous, atol=1e-12)


def test_links_placements_in_one_compiled_pass_match_pinocchio(panda, table_scene):
    """``CollisionWorld.link_transforms`` (every joint's frame by ``JointFrames``, the base's
    geometries included) is pinocchio's geometry placement of each link, and so is its
    pinocchio path, the one for joints the kernel does not model."""
    world = CollisionWorld(panda, [sh for o in table_scene.objects for sh in o.shapes])
    Q = np.random.default_rng(3).uniform(panda.lower, panda.upper, (30, panda.nq))
    H = world.link_transforms(Q)
    assert world._kinematics.supports and 0 in {
        g.parentJoint for g in world.geom_model.geometryObjects[:world.n_links]}
    assert H.shape == (30, world.n_links, 4, 4) and world.link_transforms(Q[:0]).shape[0] == 0
    for i, q in enumerate(Q):
        for link, T in enumerate(world.link_placements(q)):
            np.testing.assert_allclose(H[i, link], T.homogeneous, atol=1e-12)
    world._kinematics.supports = False  # as for a joint the kernel does not model
    np.testing.assert_allclose(world.link_transforms(Q), H, atol=1e-12)


def test_exp3_matches_pinocchio():
    from advocc_ros.kinematics.ik import exp3

    w = np.random.default_rng(1).normal(0, 1.2, (50, 3))
    w[0] = 0.0
    w[1] = [np.pi - 1e-6, 0, 0]
    R = exp3(w)
    for i in range(len(w)):
        np.testing.assert_allclose(R[i], pin.exp3(w[i]), atol=1e-12)


def test_the_compiled_region_test_is_the_goal_regions(panda, table_scene):
    """``PoseBox.contains`` (compiled, rotation errors near a half turn included) says what
    ``GoalRegion.contains`` (pinocchio) says, on poses inside, outside and at the edges."""
    import dataclasses

    from advocc_ros.kinematics.ik import goal_box

    goal = dataclasses.replace(table_scene.goal, orientation_tolerance_rad=(np.pi, 0.4, 3.0))
    box, T_c = goal_box(panda, goal), goal.center.to_se3()
    T_link_tool = goal.tool_offset.to_se3()
    rng = np.random.default_rng(2)
    w = rng.uniform(-3.2, 3.2, (400, 3)) * [1.0, 0.15, 1.0]
    w[:40] = np.array([np.pi - 1e-6, 0.0, 0.0]) * rng.choice([-1, 1], (40, 1))  # half turns
    p = rng.uniform(-1.3, 1.3, (400, 3)) * np.asarray(goal.position_tolerance_m)
    links = np.array([(T_c * pin.SE3(pin.exp3(w[i]), p[i]) * T_link_tool.inverse()).homogeneous
                      for i in range(400)])
    inside = box.contains(links)
    expected = [goal.contains(pin.SE3(T) * T_link_tool) for T in links]
    assert 50 < inside.sum() < 350 and inside[:40].any()
    np.testing.assert_array_equal(inside, expected)


def test_compiled_ik_steps_like_pinocchios_dls(panda, table_scene, chain):
    """The compiled batch IK takes pinocchio's DLS steps (``kinematics.ik.dls_ik``, one
    configuration at a time): the same rows reach the region, at the same configurations."""
    from advocc_ros.kinematics.ik import IkConfig

    goal, cfg = table_scene.goal, IkConfig()
    sampler = GoalSampler(panda, None, goal, np.random.default_rng(5))
    starts, targets, iterations = sampler.draw(48)
    iterations = np.random.default_rng(6).integers(5, 60, 48)
    Q, reached = dls(chain, starts, targets, iterations, cfg.ik_damping,
                     GoalSampler.max_step_rad, panda.lower, panda.upper, sampler.box)
    assert 5 <= reached.sum() < 48
    for i in range(48):
        q = sampler.solve(starts[i], targets[i], iterations[i])
        assert (q is not None) == reached[i]
        if q is not None:
            np.testing.assert_allclose(Q[i], q, atol=1e-7)


def test_planner_goals_are_valid_goal_configurations_and_follow_their_seed(panda, table_scene):
    world = CollisionWorld(panda, [sh for o in table_scene.objects for sh in o.shapes])
    draw = planner_goals(panda, table_scene.goal, world.collisions_batch, 64, seed=3)
    assert len(draw.Q) == 64 and draw.converged >= 64 and draw.attempts >= draw.converged
    region = GoalSampler(panda, world.in_collision, table_scene.goal,
                         np.random.default_rng(0))
    assert all(region.region_distance(q) == 0.0 for q in draw.Q)
    assert not world.collisions_batch(draw.Q).any()
    assert np.all((draw.Q >= panda.lower) & (draw.Q <= panda.upper))
    again = planner_goals(panda, table_scene.goal, world.collisions_batch, 64, seed=3)
    np.testing.assert_array_equal(again.Q, draw.Q)
    other = planner_goals(panda, table_scene.goal, world.collisions_batch, 64, seed=4)
    assert not np.array_equal(other.Q, draw.Q)


def test_the_planners_one_at_a_time_sampler_draws_the_same_goals(panda, table_scene):
    """One goal sampler: a planner's attempts, one at a time through pinocchio, are the
    attempts of the batches, so both find the same goal configurations from one seed."""
    world = CollisionWorld(panda, [sh for o in table_scene.objects for sh in o.shapes])
    draw = planner_goals(panda, table_scene.goal, world.collisions_batch, 16, seed=9,
                         attempts_per_sample=32)  # one full batch of 512 attempts
    sampler = GoalSampler(panda, world.in_collision, table_scene.goal,
                          np.random.default_rng(9))
    one_at_a_time = np.array(sampler.sample(16, float('inf')))
    assert len(draw.Q) == 16 and sampler.attempts <= draw.attempts
    np.testing.assert_allclose(one_at_a_time, draw.Q, atol=1e-6)


def test_a_region_with_no_solution_spends_its_attempt_budget(panda, table_scene):
    import dataclasses

    from advocc_ros.model.pose import Pose

    far = dataclasses.replace(table_scene.goal, center=Pose((3.0, 0.0, 0.5)))
    draw = planner_goals(panda, far, lambda Q: np.zeros(len(Q), bool), 8, seed=0,
                         attempts_per_sample=4)
    assert draw.Q.shape == (0, panda.nq) and draw.attempts == 32 and draw.converged == 0


def test_task_goals_are_cached_per_task_and_on_disk(panda, table_scene, tmp_path,
                                                    monkeypatch, caplog):
    from advocc_ros.kinematics import goal_batch
    from advocc_ros.model.cache import CACHE_ENV, clear_task_caches

    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    clear_task_caches()
    first = task_goals(panda, table_scene.objects, table_scene.goal, 32)
    assert task_goals(panda, table_scene.objects, table_scene.goal, 32) is first
    assert len(first.Q) == 32
    (path,) = tmp_path.glob('*.goals.npz')
    clear_task_caches()  # a new process reads the file, sampling nothing
    monkeypatch.setattr(goal_batch, 'planner_goals', lambda *a: pytest.fail('sampled again'))
    again = task_goals(panda, table_scene.objects, table_scene.goal, 32)
    np.testing.assert_array_equal(again.Q, first.Q)
    assert again.attempts == first.attempts
    monkeypatch.undo()
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    moved = first.Q.copy()
    moved[0, 0] += 0.5  # no longer a goal configuration: the file is not used
    np.savez(path, Q=moved, attempts=1, converged=1)
    clear_task_caches()
    fresh = task_goals(panda, table_scene.objects, table_scene.goal, 32)
    np.testing.assert_array_equal(fresh.Q, first.Q)
    assert 'goal sample cache' in caplog.text
    path.write_bytes(b'not a zip')
    clear_task_caches()
    assert len(task_goals(panda, table_scene.objects, table_scene.goal, 32).Q) == 32


def test_rarest_first_puts_an_isolated_point_first():
    rng = np.random.default_rng(0)
    Q = np.concatenate([rng.normal(0, 0.01, (30, 7)), np.full((1, 7), 2.0)])
    order = rarest_first(Q, k=5)
    assert order[0] == 30 and sorted(order) == list(range(31))
    assert list(rarest_first(Q[:3], k=5)) == [0, 1, 2]
