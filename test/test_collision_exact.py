"""The fast validity path gives the all-pairs verdicts, configuration by configuration.

``CollisionWorld.in_collision`` (broad phase, used for every state OMPL samples),
``collisions_batch`` and ``first_collision`` (the motion validator) against pinocchio's
all-pairs ``computeCollisions`` over the same geometry model and SRDF pairs, on 40,000 random
configurations per shipped scene. And the motion validator against OMPL's own
``DiscreteMotionValidator`` on random motions.
"""

import pathlib

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.model.collision import CollisionWorld, no_warm_start
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

SCENES = sorted((pathlib.Path(__file__).resolve().parents[1] / 'config' / 'scenes').glob('*.yaml'))
N_CONFIGS = 16_000


def _all_pairs(world: CollisionWorld, Q: np.ndarray) -> np.ndarray:
    """Every SRDF self pair and every (link, shape) pair through GJK, cold, in C++."""
    pool = pin.GeometryPool(world.model, world.geom_model, 2)
    for data in pool.getGeometryDatas():
        no_warm_start(data.collisionRequests)
    return np.asarray(pin.computeCollisionsInParallel(2, pool, np.asfortranarray(Q.T), True,
                                                      False), dtype=bool)


@pytest.mark.slow  # 16,000 configurations per scene, checked three times
@pytest.mark.parametrize('path', SCENES, ids=[p.stem for p in SCENES])
def test_broad_phase_matches_all_pairs(path):
    scene = load_scene(path)
    robot = load_robot(scene.robot)
    world = CollisionWorld(robot, scene.shapes)
    Q = robot.sample_q(np.random.default_rng(14), N_CONFIGS)
    reference = _all_pairs(world, Q)
    assert 0.02 < reference.mean() < 0.5  # both verdicts are well represented
    single = np.fromiter((world.in_collision(q) for q in Q), dtype=bool, count=len(Q))
    assert np.array_equal(single, reference), np.nonzero(single != reference)[0][:10]
    batch = world.collisions_batch(Q, threads=2)
    assert np.array_equal(batch, reference)
    # Checked in reverse order, nothing changes: no verdict depends on the previous query.
    backwards = np.fromiter((world.in_collision(q) for q in Q[:8_000][::-1]), dtype=bool)
    assert np.array_equal(backwards[::-1], reference[:8_000])
    # first_collision: the first colliding index of each run of 50, as a loop would find it.
    for start in range(0, 5_000, 50):
        flags = reference[start:start + 50]
        expected = int(np.argmax(flags)) if flags.any() else -1
        assert world.first_collision(Q[start:start + 50]) == expected


@pytest.mark.processes
def test_motion_validator_matches_ompl(panda, table_scene):
    from ompl import base as ob

    from advocc_ros.planning.motion import make_motion_validator
    from advocc_ros.planning.solve import joint_space

    world = CollisionWorld(panda, table_scene.shapes)
    nq = panda.nq

    def space_info(batch: bool):
        space = joint_space(ob, panda)
        si = ob.SpaceInformation(space)
        calls = [0]

        def valid(state):
            calls[0] += 1
            return not world.in_collision(np.array([state[i] for i in range(nq)]))

        si.setStateValidityChecker(ob.StateValidityCheckerFn(valid))
        si.setStateValidityCheckingResolution(0.01 / space.getMaximumExtent())
        checks = [0]
        if batch:
            si.setMotionValidator(make_motion_validator(ob, si, space, world, nq, checks))
        si.setup()
        return si, space, calls, checks

    ours, ours_space, ours_calls, ours_checks = space_info(True)
    theirs, theirs_space, theirs_calls, _ = space_info(False)
    rng = np.random.default_rng(3)
    starts = [q for q in panda.sample_q(rng, 600) if not world.in_collision(q)][:150]
    ends = panda.sample_q(rng, len(starts))
    verdicts = []
    for a, b in zip(starts, ends):
        # short and long motions: the whole range, and a tenth of it
        for end in (b, a + 0.1 * (b - a)):
            s1, s2 = ob.State(ours_space), ob.State(ours_space)
            for i in range(nq):
                s1[i], s2[i] = float(a[i]), float(end[i])
            theirs_calls[0] = 0
            expected = theirs.checkMotion(s1(), s2())
            ours_checks[0] = 0
            got = ours.checkMotion(s1(), s2())
            assert got == expected
            assert ours_checks[0] == theirs_calls[0]  # the same states, in the same order
            verdicts.append(got)
    assert 0.1 < np.mean(verdicts) < 0.9


@pytest.mark.parametrize('path', SCENES, ids=[p.stem for p in SCENES])
def test_clearances_match_all_pair_distances(path):
    """The bounding-box filter of ``scene_clearances`` skips only pairs that are capped."""
    scene = load_scene(path)
    robot = load_robot(scene.robot)
    world = CollisionWorld(robot, scene.shapes)
    Q = robot.sample_q(np.random.default_rng(5), 3000)
    Q = Q[~world.collisions_batch(Q)][:400]
    upto = 0.1
    fast = world.scene_clearances(Q, upto)
    exact = []
    for q in Q:  # every (link, shape) pair, one distance query each
        pin.updateGeometryPlacements(world.model, world.data, world.dist_model,
                                     world.dist_data, q)
        exact.append(min([pin.computeDistance(world.dist_model, world.dist_data, k).min_distance
                          for k in range(len(world.dist_model.collisionPairs))] + [upto]))
    assert np.array_equal(fast, np.array(exact))
    assert (fast < upto).any()  # near configurations were checked, not only capped ones
