"""The continuous certificate (conservative advancement) and the holes it closes.

Each test here fails on the code before it (HEAD ec4ef43): the old ``certify`` checked states
0.005 rad apart, ignored a missing locked joint (NaN compares False), took the start as an
option, and the witness search kept a failed search for the process's lifetime.
"""

import numpy as np
import pytest
import yaml

from advocc_ros.attack.policy import WitnessBodies
from advocc_ros.attack.solvable import CERTIFICATE, Verdict, assess
from advocc_ros.kinematics.ik import goal_configuration, start_configuration
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import make_box
from advocc_ros.planning import witness as witness_mod
from advocc_ros.planning import witness_cache
from advocc_ros.planning.certificate import CertificateConfig, certify_path
from advocc_ros.planning.witness import Witness, certify, witness_states
from advocc_ros.planning.witness_cache import find_witnesses

OLD_STEP_RAD = 0.005
"""The step of the old per-state check."""


@pytest.fixture(autouse=True)
def _no_scripted_witness_kept():
    """Tests here put scripted witnesses in the process's witness cache: none outlives its
    test, so later tests search for the real one."""
    yield
    witness_cache.WITNESSES.clear()


@pytest.fixture(scope='module')
def task(table_scene):
    """table_pick and a witness found without a planner (no process: the fast lane runs these
    tests): the straight joint-space line from the start to the damped-least-squares goal
    configuration, which the certificate proves on the unattacked scene (tested below)."""
    robot = load_robot(table_scene.robot)
    q0 = start_configuration(table_scene, robot)
    q_goal = goal_configuration(robot, table_scene.goal, q0)
    witness = Witness(robot.joint_names, np.array([q0, q_goal]), dict(robot.locked_values),
                      {'planner': 'straight line to the DLS goal configuration'})
    return table_scene, robot, q0, witness


def _old_check_passes(robot, world, goal, Q) -> bool:
    """The old certificate: every state 0.005 rad apart free, the last one in the goal."""
    states = witness_states(Q, OLD_STEP_RAD)
    data = robot.create_data()
    import pinocchio as pin
    pin.framesForwardKinematics(robot.model, data, states[-1])
    tool = data.oMf[robot.model.getFrameId(goal.link)] * goal.tool_offset.to_se3()
    return world.first_collision(states) < 0 and goal.contains(tool)


def _speck_between_states(robot, scene, Q):
    """A 0.2 mm cube that a link corner sweeps through between two of the old check's states
    while no checked state touches it: (the cube, the configuration where the path hits it).
    A corner that is extreme sideways to its motion clips it and moves on."""
    states = witness_states(Q, OLD_STEP_RAD)
    k = len(states) // 2
    q_mid = (states[k] + states[k + 1]) / 2
    world = CollisionWorld(robot, scene.shapes)
    placements = [[T.copy() for T in world.link_placements(q)]  # oMg is overwritten
                  for q in (states[k], q_mid, states[k + 1])]
    candidates = []
    for g, mesh in enumerate(robot.link_meshes):
        v = np.asarray(mesh.vertices, float)
        at = [T.rotation @ v.T + T.translation[:, None] for T in (p[g] for p in placements)]
        swept = np.linalg.norm(at[2] - at[0], axis=0)
        candidates += [(swept[i], at[1][:, i]) for i in np.argsort(-swept)[:60]]
    for _, point in sorted(candidates, key=lambda c: -c[0]):
        speck = make_box('speck', point, (0.0002,) * 3)
        with_speck = CollisionWorld(robot, scene.shapes + list(speck.shapes))
        if with_speck.in_collision(q_mid) and not with_speck.in_collision(states[k]) \
                and not with_speck.in_collision(states[k + 1]) \
                and with_speck.first_collision(states) < 0:
            return speck, q_mid
    raise AssertionError('no corner sweeps past a speck between two checked states')


def test_a_speck_between_two_checked_states_is_not_certified(task):
    scene, robot, q0, witness = task
    Q = witness.configurations(robot)
    speck, q_hit = _speck_between_states(robot, scene, Q)
    world = CollisionWorld(robot, scene.shapes + list(speck.shapes))
    assert world.in_collision(q_hit)  # the path really runs into it
    assert _old_check_passes(robot, world, scene.goal, Q)  # and the old check said certified
    verdict = assess(robot, scene.objects, (speck,), scene.goal, witness, q0)
    assert verdict.verdict == Verdict.UNKNOWN, verdict.message
    assert 'speck' in verdict.message and 'segment' in verdict.message
    why, proof = certify(robot, world, scene.goal, witness, q0)
    assert why is not None and proof.segment is not None and 0 <= proof.fraction <= 1
    hit_at = np.linalg.norm(q_hit - Q[proof.segment]) / np.linalg.norm(
        Q[proof.segment + 1] - Q[proof.segment])
    assert proof.fraction <= hit_at + 1e-9  # it stops at or before the contact


def test_the_unattacked_witness_is_proven_with_few_states(task):
    scene, robot, q0, witness = task
    why, proof = certify(robot, CollisionWorld(robot, scene.shapes), scene.goal, witness, q0)
    assert why is None and proof.proven
    # Far fewer states than a 0.005 rad list of the same path, each pair measured exactly.
    assert 0 < proof.states < len(witness_states(witness.configurations(robot), OLD_STEP_RAD))
    assert proof.min_clearance_m >= CERTIFICATE.floor_m


def test_a_pair_below_the_floor_fails_and_is_named(task):
    """A lid 0.05 mm above the highest point the robot reaches along the witness: no state
    touches it, but the gap is below the 0.1 mm floor, so the path is not proven; the verdict
    says where and which pair."""
    scene, robot, q0, witness = task
    Q = witness.configurations(robot)
    states = witness_states(Q, 0.0005)
    world = CollisionWorld(robot, scene.shapes)
    H = world.link_transforms(states)
    top = (-np.inf, None, None, None)
    for g, mesh in enumerate(robot.link_meshes):
        v = np.einsum('nij,kj->nki', H[:, g, :3, :3], np.asarray(mesh.vertices)) \
            + H[:, g, None, :3, 3]
        n, i = np.unravel_index(np.argmax(v[..., 2]), v.shape[:2])
        if v[n, i, 2] > top[0]:
            top = (v[n, i, 2], v[n, i], g, n)
    _, point, g, n = top
    box = make_box('lid', point + np.array([0, 0, 0.005 + 0.00005]), (0.01,) * 3)
    boxed = CollisionWorld(robot, scene.shapes + list(box.shapes))
    assert boxed.first_collision(states) < 0
    proof = certify_path(boxed, Q, shape_names=[o.id for o in scene.objects] + ['lid'])
    assert not proof.proven and proof.pair == (robot.link_names[g], 'lid'), proof.message
    assert 'below the 0.1 mm floor' in proof.message
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))])
    at = arc[proof.segment] + proof.fraction * (arc[proof.segment + 1] - arc[proof.segment])
    top_at = np.sum(np.linalg.norm(np.diff(states[:n + 1], axis=0), axis=1))
    assert top_at - 0.05 < at <= top_at + 1e-6  # stops just before the top, not elsewhere


def test_a_witness_without_the_locked_joints_is_not_certified(task):
    scene, robot, q0, witness = task
    world = CollisionWorld(robot, scene.shapes)
    assert robot.locked_values  # the Panda's fingers
    bare = Witness(witness.joint_names, witness.waypoints, {}, witness.source)
    why = certify(robot, world, scene.goal, bare, q0).why
    assert why is not None and 'locked joint' in why
    other = dict(witness.locked, **{next(iter(witness.locked)): 0.0001})
    assert 'locked joint' in certify(robot, world, scene.goal,
                                     Witness(witness.joint_names, witness.waypoints, other),
                                     q0).why


def test_the_start_is_required_and_checked(task):
    scene, robot, q0, witness = task
    world = CollisionWorld(robot, scene.shapes)
    with pytest.raises(TypeError):
        certify(robot, world, scene.goal, witness)  # pylint: disable=no-value-for-parameter
    with pytest.raises(TypeError):
        assess(robot, scene.objects, (), scene.goal, witness)  # pylint: disable=E1120
    for offset in (0.05, 2e-9):
        moved = q0.copy()
        moved[3] += offset
        why = certify(robot, world, scene.goal, witness, moved).why
        assert why is not None and 'start' in why
    assert certify(robot, world, scene.goal, witness, q0 + 5e-10).why is None
    verdict = assess(robot, scene.objects, (), scene.goal, witness, q0 + 0.05)
    assert verdict.verdict != Verdict.CERTIFIED and 'start' in verdict.message


def test_a_failed_search_is_not_kept(task, monkeypatch, tmp_path):
    scene, robot, q0, witness = task
    monkeypatch.setenv(witness_mod.CACHE_ENV, str(tmp_path))
    witness_cache.WITNESSES.clear()
    calls, answers = [], [(), (witness,)]
    monkeypatch.setattr(witness_cache, 'search_witnesses',
                        lambda *a: calls.append(a) or answers.pop(0))
    assert find_witnesses(robot, scene.objects, q0, scene.goal) == ()
    assert len(calls) == 1 and not list(tmp_path.iterdir())  # no path: no other seed either
    again = find_witnesses(robot, scene.objects, q0, scene.goal)  # searches again
    assert again == (witness,) and len(calls) == 2
    assert find_witnesses(robot, scene.objects, q0, scene.goal)[0] is witness  # now kept
    assert len(calls) == 2 and len(list(tmp_path.iterdir())) == 1


def _scripted_runs(monkeypatch, robot, answers):
    """The search with no rare ends and its RRTConnect runs answered from ``answers`` (a
    planning worker still starts); returns the (seed, simplified) of each run."""
    runs = []
    monkeypatch.setattr(witness_mod, 'rare_clear_ends',
                        lambda *a, **k: np.zeros((0, robot.nq)))
    monkeypatch.setattr(witness_mod, 'plan_witness',
                        lambda planner, robot, q, goal, q_end, time_s, seed, simplify:
                        runs.append((seed, simplify)) or answers.pop(0))
    return runs


@pytest.mark.processes  # the search's planning worker starts (its runs are scripted)
def test_an_unproven_path_is_dropped_for_the_next_seed(task, monkeypatch):
    """A path the continuous certificate cannot prove (here: through the table) is not a
    witness; the next seed's is."""
    scene, robot, q0, witness = task
    monkeypatch.setenv(witness_mod.CACHE_ENV, 'off')
    witness_cache.WITNESSES.clear()
    down = np.insert(witness.waypoints, 1, q0 + np.array([0, 1.2, 0, 0, 0, 1.5, 0]), 0)
    bad = Witness(witness.joint_names, down, witness.locked)
    runs = _scripted_runs(monkeypatch, robot, [bad, witness])
    assert find_witnesses(robot, scene.objects, q0, scene.goal) == (witness,)
    assert runs == [(witness_mod.WITNESS_SEED, True), (witness_mod.WITNESS_SEED + 1, True)]


@pytest.mark.processes  # the search's planning workers start (their runs are scripted)
def test_unproven_simplified_paths_are_searched_again_unsimplified(task, monkeypatch):
    """When every simplified path grazes an object (a grasp in a pocket), the targets are
    searched again without simplification."""
    scene, robot, q0, witness = task
    monkeypatch.setenv(witness_mod.CACHE_ENV, 'off')
    witness_cache.WITNESSES.clear()
    down = np.insert(witness.waypoints, 1, q0 + np.array([0, 1.2, 0, 0, 0, 1.5, 0]), 0)
    bad = Witness(witness.joint_names, down, witness.locked)
    tries = witness_mod.WITNESS_TRIES
    runs = _scripted_runs(monkeypatch, robot, [bad] * tries + [witness])
    assert find_witnesses(robot, scene.objects, q0, scene.goal) == (witness,)
    assert [simplified for _, simplified in runs] == [True] * tries + [False]


def test_the_verdict_is_an_enum_with_the_old_words(task):
    scene, robot, q0, witness = task
    verdict = assess(robot, scene.objects, (), scene.goal, witness, q0)
    assert verdict.verdict is Verdict.CERTIFIED and verdict.verdict == 'certified'
    data = verdict.to_json()
    assert type(data['verdict']) is str and data['verdict'] == 'certified'
    assert yaml.safe_load(yaml.safe_dump(data))['verdict'] == 'certified'
    assert [v.value for v in Verdict] == ['certified', 'goal blocked', 'unknown']
    assert f'{Verdict.GOAL_BLOCKED}' == 'goal blocked' and data['witness_states'] > 0


def test_guard_step_keeps_the_path_off_the_boxes(task):
    """The guard's arithmetic: half a guard step moves no point more than the margin minus
    twice the floor, and the Panda's margin is the ~1 mm measured as what makes attacks bite."""
    scene, robot, q0, witness = task
    bodies = WitnessBodies(robot, CollisionWorld(robot), witness)
    L = robot.motion_bound.max_m_per_rad
    assert L * bodies.step_rad / 2 == pytest.approx(
        CERTIFICATE.guard_margin_m - 2 * CERTIFICATE.floor_m)
    assert CERTIFICATE.guard_margin_m == pytest.approx(0.001)
    gaps = np.linalg.norm(np.diff(bodies.states, axis=0), axis=1)
    assert gaps.max() <= bodies.step_rad + 1e-12


@pytest.mark.parametrize('bad', [dict(floor_m=0.0), dict(floor_m=-1.0),
                                 dict(guard_margin_m=0.0002), dict(max_states=0),
                                 dict(lookahead_rad=float('nan'))])
def test_certificate_config_rejects_bad_values(bad):
    with pytest.raises(ValueError):
        CertificateConfig(**bad)


def test_guard_bodies_agree_with_a_plain_check(task):
    """The guard's fast paths (placements from one FK per state, the box pre-test) give the
    verdicts of a plain geometry update + coal collide over every (state, link) pair."""
    import coal
    from advocc_ros.attack.bodies import LinkBoxes

    scene, robot, q0, witness = task
    world = CollisionWorld(robot)
    bodies = WitnessBodies(robot, world, witness)
    for q, R, t in zip(bodies.states[::50], bodies.boxes.R[::50], bodies.boxes.t[::50]):
        plain = world.link_placements(q)
        np.testing.assert_allclose(R, [T.rotation for T in plain], atol=1e-12)
        np.testing.assert_allclose(t, [T.translation for T in plain], atol=1e-12)
    rng = np.random.default_rng(3)
    states = bodies.states[::25]
    sparse = LinkBoxes(world, states)  # the same bodies on a subset of the states
    request, touched = coal.CollisionRequest(), 0
    for _ in range(150):  # near the body: some touch it, some do not
        near = sparse.centres_m[rng.integers(len(states)), rng.integers(world.n_links)]
        centre, size = near + rng.normal(0.0, 0.1, 3), rng.uniform(0.01, 0.1)
        box = coal.Box(size, size, size)
        tf = coal.Transform3s(np.eye(3), centre)
        plain = [any(coal.collide(box, tf, world.geom_model.geometryObjects[g].geometry,
                                  coal.Transform3s(T.rotation, T.translation), request,
                                  coal.CollisionResult())
                     for g, T in enumerate(world.link_placements(q))) for q in states]
        assert sparse.touched_by(centre, size) == any(plain), (centre, size)
        np.testing.assert_array_equal(sparse.blocked_by(centre, size), plain)
        touched += any(plain)
    assert 10 < touched < 140  # both answers occur
