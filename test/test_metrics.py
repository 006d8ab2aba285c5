"""Metrics equal hand-computed values on fixed paths (docs/metrics.md)."""

import numpy as np
import pytest

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.evaluation.metrics import (MetricsConfig, PathInCollision, TrialRecord,
                                           aggregate, densify, format_value, joint_deviation,
                                           min_clearance, min_manipulability, random_directions)
from advocc_ros.model.scene import make_box

Q_READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def test_jds_exact():
    q0 = np.zeros(7)
    path = np.array([q0, [3.0, 4.0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 2.0]])
    assert joint_deviation(path, q0) == pytest.approx((0.0 + 5.0 + 2.0) / 3, abs=1e-15)


def test_densify_spacing_and_endpoints():
    path = np.array([np.zeros(7), np.full(7, 0.1), np.full(7, 0.1)])
    dense = densify(path, 0.01)
    np.testing.assert_array_equal(dense[0], path[0])
    np.testing.assert_allclose(dense[-1], path[-1])
    assert np.linalg.norm(np.diff(dense, axis=0), axis=1).max() <= 0.01 + 1e-12


def _fd_manipulability(robot, q, h=1e-6):
    """Yoshikawa index from a Jacobian built by central differences of forward kinematics
    (tool origin velocity and world angular velocity), independent of pinocchio's Jacobian."""
    import pinocchio as pin

    data = robot.model.createData()

    def pose(x):
        pin.framesForwardKinematics(robot.model, data, x)
        T = data.oMf[robot.ee_frame]
        return T.translation.copy(), T.rotation.copy()

    cols = []
    for j in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[j] = h
        (p1, R1), (p0, R0) = pose(q + dq), pose(q - dq)
        cols.append(np.concatenate([(p1 - p0) / (2 * h), pin.log3(R1 @ R0.T) / (2 * h)]))
    J = np.array(cols).T
    return np.sqrt(max(np.linalg.det(J @ J.T), 0.0))


def test_smr_is_min_manipulability_along_dense_path(panda):
    # joint 5 swept through the ready pose: the index dips at the middle, not at the waypoints
    a = Q_READY + np.array([0, 0, 0, 0, -1.4, 0, 0])
    b = Q_READY + np.array([0, 0, 0, 0, 1.4, 0, 0])
    path = np.array([a, b])
    dense = [a + t * (b - a) for t in np.linspace(0.0, 1.0, 401)]
    expected = min(_fd_manipulability(panda, q) for q in dense)
    got = min_manipulability(panda, path, 0.005)
    assert got == pytest.approx(expected, rel=1e-4)
    ends = min(_fd_manipulability(panda, a), _fd_manipulability(panda, b))
    assert got < ends - 1e-3  # the minimum lies between the waypoints: interpolation matters
    assert got == pytest.approx(_fd_manipulability(panda, Q_READY), rel=1e-4)


def _brute_force_clearance(world, path, directions, t_max, step):
    """First invalid point along each ray on a fine grid (limits count as collision)."""
    robot = world.robot
    best = np.inf
    ts = np.arange(step, t_max + 1e-12, step)
    for q, rays in zip(path, directions):
        for u in rays:
            Q = q + ts[:, None] * u
            bad = np.any((Q < robot.lower) | (Q > robot.upper), axis=1)
            bad |= world.collisions_batch(Q)
            if bad.any():
                best = min(best, ts[np.argmax(bad)])
    return best


def test_cmr_matches_brute_force_line_search(panda):
    hand = panda.ee_pose(Q_READY).translation
    box = make_box('box', hand + np.array([0.0, 0.0, -0.22]), (0.1, 0.1, 0.1))
    world = CollisionWorld(panda, list(box.shapes))
    assert not world.in_collision(Q_READY)
    path = np.array([Q_READY, Q_READY + 0.05])
    cfg = MetricsConfig(cmr_range_rad=0.3)
    dirs = random_directions(np.random.default_rng(1), len(path), 6, panda.nq)
    got = min_clearance(world, path, cfg, directions=dirs)
    brute = _brute_force_clearance(world, path, dirs, cfg.cmr_range_rad, 2.5e-4)
    assert brute < cfg.cmr_range_rad  # the obstacle is within range
    assert abs(got - brute) <= cfg.cmr_resolution_rad + 2.5e-4, (got, brute)


def test_cmr_caps_at_range_and_refuses_a_colliding_path(panda):
    world = CollisionWorld(panda, [])
    cfg = MetricsConfig(cmr_range_rad=0.05, cmr_limits_as_collision=False)
    assert min_clearance(world, np.array([Q_READY]), cfg) == pytest.approx(0.05)
    hand = panda.ee_pose(Q_READY).translation
    blocked = CollisionWorld(panda, list(make_box('b', hand, (0.1, 0.1, 0.1)).shapes))
    free = Q_READY + np.array([1.0, 0, 0, 0, 0, 0, 0])
    assert not blocked.collisions_batch(free[None], 1)[0]
    with pytest.raises(PathInCollision, match='waypoint 1 is in collision') as err:
        min_clearance(blocked, np.array([free, Q_READY]), cfg)
    assert err.value.index == 1


def test_cmr_joint_limits_count_as_collision(panda):
    q = Q_READY.copy()
    q[0] = panda.upper[0] - 0.01  # 10 mrad from the joint-1 limit, far from any obstacle
    world = CollisionWorld(panda, [])
    dirs = np.zeros((1, 2, 7))
    dirs[0, 0, 0], dirs[0, 1, 0] = 1.0, -1.0
    got = min_clearance(world, np.array([q]), MetricsConfig(), directions=dirs)
    assert got == pytest.approx(0.01, abs=MetricsConfig().cmr_resolution_rad)


def test_aggregate_hand_values():
    recs = [
        TrialRecord(0, 0, True, 'SUCCESS', 0.5, min_manipulability=0.04, min_clearance_rad=0.02,
                    jds_rad=1.0),
        TrialRecord(1, 1, True, 'SUCCESS', 1.5, min_manipulability=0.06, min_clearance_rad=0.04,
                    jds_rad=2.0),
        TrialRecord(2, 2, False, 'TIMED_OUT', 4.9),
        TrialRecord(3, 3, False, 'NO_IK_SOLUTION', 0.2),
    ]
    row = aggregate(recs, time_budget_s=5.0)
    assert row['psr'] == 0.5
    assert row['smr'] == pytest.approx(5.0)   # mean 0.05, x10^-2
    assert row['cmr'] == pytest.approx(3.0)   # mean 0.03, x10^-2
    assert row['jds'] == pytest.approx(1.5)
    assert row['pt'] == pytest.approx((0.5 + 1.5 + 5.0 + 5.0) / 4)  # failures = full budget


def test_aggregate_na_when_nothing_succeeds():
    row = aggregate([TrialRecord(0, 0, False, 'TIMED_OUT', 1.0),
                     TrialRecord(1, 1, False, 'GOAL_IN_COLLISION', 0.1)], time_budget_s=5.0)
    assert row['psr'] == 0.0
    assert row['smr'] is None and row['cmr'] is None and row['jds'] is None
    assert row['pt'] == 5.0
    assert format_value(row['smr']) == 'N/A'


def test_internal_errors_stay_out_of_psr_and_pt_but_are_counted():
    recs = [TrialRecord(0, 0, True, 'SUCCESS', 1.0, min_manipulability=0.05,
                        min_clearance_rad=0.02, jds_rad=1.0),
            TrialRecord(1, 1, False, 'PLANNING_FAILED', 2.0),
            TrialRecord(6, 6, False, 'INVALID_MOTION_PLAN', 1.5),  # a planner failure
            TrialRecord(2, 2, False, 'INTERNAL_ERROR', 0.0),   # the worker raised
            TrialRecord(3, 3, False, 'CRASH', 0.0),            # an older shim's dead worker
            TrialRecord(4, 4, False, '-999', 0.0),             # a code without a name
            TrialRecord(5, 5, True, 'TIMED_OUT', 5.0)]         # contradicts itself
    row = aggregate(recs, time_budget_s=5.0)
    assert row['trials'] == 7 and row['internal_errors'] == 4
    assert row['psr'] == pytest.approx(1 / 3)  # 1 success of the 3 trials that measured it
    assert row['pt'] == pytest.approx((1.0 + 5.0 + 5.0) / 3)
    assert row['failures'] == {'goal not sampled': 0, 'timed out': 0, 'planning failed': 1,
                               'invalid path': 1, 'goal invalid for victim': 0,
                               'model mismatch': 0}
    only_errors = aggregate(recs[3:6], time_budget_s=5.0)
    assert only_errors['psr'] is None and only_errors['pt'] is None
