"""Witnesses, certificates and the ``solvable`` goal policy on the real Panda table task.

The witness of every ``solvable`` attack is re-checked here independently of the code that
certified it: pinocchio's all-pairs ``computeCollisions`` on the robot's original collision
meshes (not the convex hulls the planners use), every SRDF self pair and every (link, object)
pair, at the guard's step (0.00083 rad for the Panda), and the boxes' distance to the hulls at
those states is at least the guard margin.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.attack import AttackConfig, AttackStatus, attack, load_obstacles
from advocc_ros.attack.policy import WitnessBodies
from advocc_ros.attack.solvable import CERTIFICATE, assess, probe_goal
from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
from advocc_ros.model.collision import CollisionWorld, coal_geometry
from advocc_ros.model.robot import load_robot
from advocc_ros.model.pose import SceneError
from advocc_ros.model.scene import make_box
from advocc_ros.planning import witness as witness_mod
from advocc_ros.planning import witness_cache
from advocc_ros.planning.witness import (Witness, certify, load_witness, save_witness,
                                         witness_file, witness_states)
from advocc_ros.planning.witness_cache import find_witnesses

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


@pytest.fixture(scope='module')
def task(table_scene):
    robot = load_robot(table_scene.robot)
    q0 = robot.q_from_names(list(table_scene.start), list(table_scene.start.values()), 'start')
    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=1500), seed=0)
    return table_scene, robot, q0, heatmap


def independent_collisions(robot, objects, Q) -> np.ndarray:
    """All-pairs verdict per configuration on the original meshes (no broad phase, no hulls)."""
    geom_model = robot.collision_model.copy()
    n_links = geom_model.ngeoms
    shapes = [sh for o in objects for sh in o.shapes]
    for i, shape in enumerate(shapes):
        geom_model.addGeometryObject(pin.GeometryObject(
            f'object/{i}', 0, 0, shape.pose.to_se3(), coal_geometry(shape)))
    geom_model.removeAllCollisionPairs()
    for a, b in robot.self_pairs:
        geom_model.addCollisionPair(pin.CollisionPair(a, b))
    for link in range(n_links):
        for k in range(len(shapes)):
            geom_model.addCollisionPair(pin.CollisionPair(link, n_links + k))
    data, geom_data = robot.model.createData(), geom_model.createData()
    return np.array([pin.computeCollisions(robot.model, data, geom_model, geom_data, q, True)
                     for q in Q])


def test_witness_search_is_deterministic_for_a_seed(task, monkeypatch):
    scene, robot, q0, _ = task
    monkeypatch.setenv(witness_mod.CACHE_ENV, 'off')  # two searches, not one and a file
    first = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    witness_cache.WITNESSES.clear()
    again = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    assert first is not None and again is not first
    assert np.array_equal(first.waypoints, again.waypoints)
    assert first.locked == robot.locked_values and first.joint_names == robot.joint_names


class _CountedSearch:
    """Calls the real witness search and counts the calls."""

    def __init__(self, monkeypatch):
        self.calls, self._search = 0, witness_cache.search_witnesses
        monkeypatch.setattr(witness_cache, 'search_witnesses', self)

    def __call__(self, *args):
        self.calls += 1
        return self._search(*args)


def _new_process(monkeypatch):
    """What a new process sees: an empty in-process cache (the disk cache stays)."""
    witness_cache.WITNESSES.clear()


@pytest.fixture
def search(tmp_path, monkeypatch):
    """The real witness search, counted, with an empty disk cache in ``tmp_path``."""
    monkeypatch.setenv(witness_mod.CACHE_ENV, str(tmp_path))
    _new_process(monkeypatch)
    return _CountedSearch(monkeypatch)


def _counted_certificates(monkeypatch) -> list:
    """The disk cache's certificates from now on, one list entry each."""
    calls, real = [], witness_cache.certify
    monkeypatch.setattr(witness_cache, 'certify', lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


def test_the_disk_cache_spares_the_next_process_the_search(task, tmp_path, monkeypatch, search):
    """And the certificate too: the file's digest is of the paths it proved."""
    scene, robot, q0, _ = task
    first = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    (cached,) = tmp_path.glob('*.yaml')  # beside it: the task's goal sample the search used
    _new_process(monkeypatch)
    certified = _counted_certificates(monkeypatch)
    again = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    assert search.calls == 1 and again is not first and certified == []
    # A file without the digest (an earlier version's) is certified once and given it.
    candidates = witness_cache.load_candidates(cached)
    witness_cache.save_candidates(cached, candidates)
    for _ in range(2):
        _new_process(monkeypatch)
        find_witnesses(robot, scene.objects, q0, scene.goal)
    assert len(certified) == len(candidates) and 'proof_digest' in witness_cache.read_yaml(cached)
    np.testing.assert_array_equal(again.waypoints, first.waypoints)  # the same boxes follow
    # Another task (a box elsewhere) has a file of its own.
    box = make_box('elsewhere', (-0.5, 0.5, 0.2), (0.05,) * 3)
    find_witnesses(robot, scene.objects + (box,), q0, scene.goal)
    assert search.calls == 2 and len(list(tmp_path.glob('*.yaml'))) == 2 and cached.exists()


@pytest.mark.parametrize('damage', ['garbage', 'other start', 'through a wall',
                                    'through a wall, digest kept'])
def test_a_damaged_cache_file_costs_a_search_not_a_wrong_verdict(task, tmp_path, monkeypatch,
                                                                 search, damage, caplog):
    scene, robot, q0, _ = task
    good = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    (path,) = tmp_path.glob('*.yaml')
    if damage == 'garbage':
        path.write_text('joint_names: [\n')
    else:
        waypoints = good.waypoints.copy()
        if damage == 'other start':
            waypoints[0, 0] += 0.1
        else:  # the middle waypoint pushed down through the table
            waypoints = np.insert(waypoints, 1, q0 + np.array([0, 1.2, 0, 0, 0, 1.5, 0]), 0)
        digest = witness_cache.read_yaml(path)['proof_digest'] if 'kept' in damage else None
        witness_cache.save_candidates(
            path, (Witness(good.joint_names, waypoints, good.locked, good.source),), digest)
    _new_process(monkeypatch)
    again = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    assert search.calls == 2 and 'witness cache' in caplog.text
    np.testing.assert_allclose(again.waypoints, good.waypoints, atol=1e-12)
    assert witness_cache.load_candidates(path)[0].waypoints.shape == good.waypoints.shape


def test_attack_cli_reuses_the_witness_of_an_earlier_run(task, tmp_path):
    """Two ``advocc attack`` processes: the second reads the first one's witness, goal sample
    and link tables (a file each), writes nothing again, and certifies the same path."""
    scene, robot, q0, heatmap = task
    save_heatmap(heatmap, tmp_path / 'h.npz')
    cache = tmp_path / 'cache'
    env = {**os.environ, witness_mod.CACHE_ENV: str(cache)}
    runs = []
    for k in range(2):
        out = tmp_path / f'obs{k}.yaml'
        proc = subprocess.run([sys.executable, '-m', 'advocc_ros.cli', 'attack', '--scene',
                               'table_pick', '--heatmap', str(tmp_path / 'h.npz'), '--budget',
                               '1', '--policy', 'solvable', '--json', '--no-progress', '--out',
                               str(out)], capture_output=True, text=True, timeout=180, env=env)
        assert proc.returncode == 0, proc.stderr[-2000:]
        files = sorted(f for f in cache.rglob('*') if f.is_file())
        assert sorted(f.suffix for f in files) == ['.npz', '.npz', '.yaml'], files
        assert sum(f.parent.name == 'link_tables' for f in files) == 1, files
        runs.append((json.loads(proc.stdout), [f.stat().st_mtime_ns for f in files],
                     load_witness(witness_file(out)).waypoints))
    assert runs[0][1] == runs[1][1], 'the second run searched and wrote the cache again'
    assert all(r['solvable']['verdict'] == 'certified' for r, _, _ in runs)
    np.testing.assert_allclose(runs[1][2], runs[0][2], atol=1e-12)


def test_the_policy_keeps_the_candidate_that_shields_the_fewest_goals(task):
    """Of the search's candidates, the kept witness is the one whose guard leaves the boxes
    the most goal samples to cut, whatever the candidates' order; and the boxes placed with it
    leave no more of the task's goal sample valid than those placed with the worst one."""
    from advocc_ros.kinematics.goal_batch import task_goals

    scene, robot, q0, heatmap = task
    witnesses = find_witnesses(robot, scene.objects, q0, scene.goal)
    assert len(witnesses) >= 2
    results = [attack(heatmap, robot, scene.objects, q0, scene.goal, 10, 'task',
                      goal_policy='solvable', witness=order, certify=False)
               for order in (witnesses, witnesses[::-1])]
    shielded = results[0].stats['witness_shielded']
    assert len(shielded) == len(witnesses) and shielded[results[0].stats['witness_kept']] \
        == min(shielded) < max(shielded), shielded
    assert results[1].stats['witness_shielded'] == shielded[::-1]
    if shielded.count(min(shielded)) == 1:
        assert results[0].witness is results[1].witness
    goals = task_goals(robot, scene.objects, scene.goal).Q

    def valid_goals(witness):
        boxes = attack(heatmap, robot, scene.objects, q0, scene.goal, 10, 'task',
                       goal_policy='solvable', witness=witness, certify=False).obstacles
        world = CollisionWorld(robot, [sh for o in scene.objects + boxes for sh in o.shapes])
        return int((~world.collisions_batch(goals, 1)).sum())

    worst = witnesses[int(np.argmax(shielded))]
    assert valid_goals(results[0].witness) <= valid_goals(worst)


def test_primitives_grow_by_the_margin_on_each_side():
    from advocc_ros.model.scene import SceneObject
    from advocc_ros.model.shapes import Shape

    shapes = (Shape('box', (0.1, 0.2, 0.3)), Shape('sphere', (0.05,)),
              Shape('cylinder', (0.2, 0.04)),
              Shape('mesh', (), vertices=np.eye(3), faces=np.array([[0, 1, 2]])))
    [grown] = witness_mod.grown_objects((SceneObject('o', shapes),), 0.004)
    assert grown.id == 'o' and [sh.kind for sh in grown.shapes] == [sh.kind for sh in shapes]
    np.testing.assert_allclose(grown.shapes[0].dims, (0.108, 0.208, 0.308))
    np.testing.assert_allclose(grown.shapes[1].dims, (0.054,))
    np.testing.assert_allclose(grown.shapes[2].dims, (0.208, 0.044))
    assert grown.shapes[3] is shapes[3] and all(
        a.pose == b.pose for a, b in zip(grown.shapes, shapes))


def test_a_witness_search_with_a_clearance_keeps_it_from_the_scene(task):
    """Planned among the scene's grown primitives and certified on the scene itself: every
    candidate keeps the clearance (at the search's step), and the search without it does not
    always; a clearance no path can keep falls back to the scene as it is."""
    scene, robot, q0, _ = task
    world = CollisionWorld(robot, scene.shapes)

    def clearances(witnesses):
        return np.array([world.scene_clearances(witness_states(
            w.configurations(robot), witness_mod.WITNESS_STEP_RAD), 0.05).min()
            for w in witnesses])

    plain = clearances(find_witnesses(robot, scene.objects, q0, scene.goal))
    margin_m = float(np.clip(plain.min() * 2, 0.002, 0.02))
    assert plain.min() < margin_m
    clear = find_witnesses(robot, scene.objects, q0, scene.goal, clearance_m=margin_m)
    assert clear and clearances(clear).min() >= margin_m * (1 - 1e-3), clearances(clear)
    assert all(certify(robot, world, scene.goal, w, q0).why is None for w in clear)
    start_clearance = world.scene_clearances(q0[None], 1.0)[0]
    fallback = find_witnesses(robot, scene.objects, q0, scene.goal,
                              clearance_m=start_clearance + 0.01)  # the start is too close
    assert np.array_equal(clearances(fallback), plain)


def test_with_a_victim_margin_the_kept_witness_keeps_it_from_the_scene(task):
    """A victim margin ranks the candidates first by the clearance they keep from the task's
    own objects (capped at the margin): of those that keep it, the one that shields the fewest
    goals; when none does, the clearest. The clearances measured are in the stats."""
    scene, robot, q0, heatmap = task
    witnesses = find_witnesses(robot, scene.objects, q0, scene.goal)
    world = CollisionWorld(robot, scene.shapes)
    clear = np.array([world.scene_clearances(witness_states(
        w.configurations(robot), witness_mod.WITNESS_STEP_RAD), 0.05).min() for w in witnesses])
    assert len(witnesses) >= 2 and clear.min() < clear.max() < 0.05, clear

    def kept(margin_m):
        result = attack(heatmap, robot, scene.objects, q0, scene.goal, 2, 'task',  # any M: the
                        # witness is chosen before the boxes are placed (exit_rays is 0)
                        AttackConfig(goal_policy='solvable', victim_margin_m=margin_m),
                        witness=witnesses, certify=False)
        return result.stats['witness_kept'], result.stats

    shielded = kept(0.0)[1]['witness_shielded']
    margins = np.unique(clear)[:-1] + 1e-5  # each a margin some candidates keep
    for margin_m in np.unique(margins[[0, len(margins) // 2, -1]]):  # lowest, middle, highest
        index, stats = kept(float(margin_m))
        keeping = [i for i in range(len(witnesses)) if clear[i] >= margin_m]
        assert index == min(keeping, key=lambda i: shielded[i]), (margin_m, clear, shielded)
        measured = stats['witness_scene_clearance_m']
        assert measured[index] == pytest.approx(margin_m, abs=1e-6)
        assert all(c is None or c == pytest.approx(min(clear[i], margin_m), abs=1e-6)
                   for i, c in enumerate(measured))
    index, stats = kept(float(clear.max()) + 1e-3)  # none keeps it: the clearest
    assert index == int(np.argmax(clear)) and None not in stats['witness_scene_clearance_m']


def test_the_policy_returns_a_narrower_region_and_the_goal_cover_of_it(task):
    """The policy step leaves its input alone: a new region without the candidates the kept
    witness's body touches, with the guard, and the goal sample's cover over exactly those
    candidates (computed once, for the witness choice, and handed to the objective)."""
    from advocc_ros.attack import search_region
    from advocc_ros.attack.configurations import cover_matrix
    from advocc_ros.attack.policy import apply_policy
    from advocc_ros.attack.task import goal_tier
    from advocc_ros.attack.types import Task

    scene, robot, q0, heatmap = task
    witnesses = find_witnesses(robot, scene.objects, q0, scene.goal)
    assert len(witnesses) >= 2
    solvable = Task(robot, scene.objects, q0, scene.goal, 'solvable')
    region = search_region(heatmap, robot, scene.objects, q0, scene.goal)
    before = region.candidates.copy()
    Q = goal_tier(solvable).Q
    policed = apply_policy(solvable, region, AttackConfig(), witnesses, Q)
    kept = policed.region
    assert region.guard is None and np.array_equal(region.candidates, before)
    assert kept.guard is not None and any(policed.witness is w for w in witnesses)
    assert not (kept.candidates & ~region.candidates).any()
    assert 0 < kept.candidates.sum() == policed.stats['witness_clear'] < region.candidates.sum()
    world = CollisionWorld(robot, scene.shapes)
    assert (policed.goal_cover != cover_matrix(robot, world, Q, kept)).nnz == 0
    paper = apply_policy(Task(robot, scene.objects, q0, scene.goal), region, AttackConfig(),
                         witnesses, Q)
    assert paper.region is region and paper.witness is None and paper.stats == {}


@pytest.mark.parametrize('method', ['task', 'random', 'ours'])
def test_solvable_attacks_stay_certified_under_an_independent_check(task, method):
    scene, robot, q0, heatmap = task
    witnesses = find_witnesses(robot, scene.objects, q0, scene.goal)
    result = attack(heatmap, robot, scene.objects, q0, scene.goal, 10, method,
                    goal_policy='solvable', seed=3, witness=witnesses)
    assert result.status.ok and len(result.obstacles) >= 5, result.message
    assert result.solvable.verdict == 'certified', result.solvable.message
    states = WitnessBodies(robot, CollisionWorld(robot), result.witness).states
    hits = independent_collisions(robot, scene.objects + result.obstacles, states)
    assert not hits.any(), f'states {np.flatnonzero(hits)[:5]} collide'
    data = robot.create_data()
    pin.framesForwardKinematics(robot.model, data, states[-1])
    assert scene.goal.contains(data.oMf[robot.model.getFrameId(scene.goal.link)]
                               * scene.goal.tool_offset.to_se3())
    # The clearance is real: every box keeps the guard margin (1 mm) from the robot's hulls at
    # every guard state.
    world = CollisionWorld(robot, [sh for o in result.obstacles for sh in o.shapes])
    assert not world.near_scene_batch(states, CERTIFICATE.guard_margin_m * (1 - 1e-6)).any()


def test_the_paper_policy_blocks_the_goal_and_says_so(task):
    scene, robot, q0, heatmap = task
    witness = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    result = attack(heatmap, robot, scene.objects, q0, scene.goal, 5, 'task', seed=3,
                    witness=witness)
    verdict = result.solvable
    assert verdict.verdict == 'goal blocked', verdict.message
    assert verdict.goal_probe['converged'] >= 500 and verdict.goal_probe['free'] == 0
    assert verdict.goal_probe['colliding'] == verdict.goal_probe['converged']
    assert result.goal_valid_fraction == 0.0


def test_certify_finds_a_box_on_the_witness(task):
    scene, robot, q0, _ = task
    witness = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    states = witness_states(witness.configurations(robot))
    k = len(states) // 2
    data = robot.create_data()
    pin.framesForwardKinematics(robot.model, data, states[k])
    hand = data.oMf[robot.model.getFrameId('panda_hand')].translation
    box = make_box('on_path', hand, (0.05, 0.05, 0.05))
    world = CollisionWorld(robot, [sh for o in scene.objects + (box,) for sh in o.shapes])
    why, proof = certify(robot, world, scene.goal, witness, q0)
    assert why is not None and 'below the 0.1 mm floor' in why
    Q = witness.configurations(robot)
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))])
    stop = arc[proof.segment] + proof.fraction * (arc[proof.segment + 1] - arc[proof.segment])
    assert 0 < stop <= np.sum(np.linalg.norm(np.diff(states[:k + 1], axis=0), axis=1))
    verdict = assess(robot, scene.objects, (box,), scene.goal, witness, q0)
    assert 'on_path' in verdict.message
    assert verdict.verdict == 'unknown'  # one box on the path leaves free goal poses
    assert verdict.goal_probe['free'] == 1


def test_goal_probe_is_reproducible(task):
    scene, robot, _, _ = task
    world = CollisionWorld(robot, scene.shapes)
    first = probe_goal(robot, world, scene.goal, max_attempts=600)
    assert first == probe_goal(robot, world, scene.goal, max_attempts=600)
    assert first['free'] == 1 and first['attempts'] <= 1024


def test_witness_file_round_trip_and_errors(tmp_path, task):
    scene, robot, q0, _ = task
    witness = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    path = witness_file(tmp_path / 'obs.yaml')
    assert path.name == 'obs.witness.yaml'
    save_witness(path, witness)
    back = load_witness(path)
    assert np.allclose(back.waypoints, witness.waypoints, atol=1e-12)
    assert back.locked == pytest.approx(witness.locked)
    for bad, field in [({'joint_names': [], 'waypoints': []}, 'joint_names'),
                       ({'joint_names': ['a'], 'waypoints': [[0.0]]}, 'waypoints'),
                       ({'joint_names': ['a'], 'waypoints': [[0.0], ['x']]}, 'waypoints'),
                       ({'joint_names': ['a'], 'waypoints': [[0.0], [float('nan')]]},
                        'non-finite'),
                       ({'joint_names': ['a'], 'waypoints': [[0.0], [1.0]], 'locked': [1]},
                        'locked')]:
        with pytest.raises(SceneError, match=field):
            Witness.from_data(bad)
    wrong = Witness(('a', 'b'), np.zeros((2, 2)), {})
    assert 'not the robot' in certify(robot, CollisionWorld(robot), scene.goal, wrong, q0)[0]


def test_solvable_is_refused_for_planner_in_the_loop_methods(task):
    scene, robot, q0, heatmap = task
    witness = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    result = attack(heatmap, robot, scene.objects, q0, scene.goal, 2, 'pfa',
                    goal_policy='solvable', witness=witness)
    assert result.status == AttackStatus.INVALID_REQUEST and 'solvable' in result.message


def test_cli_writes_the_witness_beside_the_obstacles(tmp_path, task):
    scene, robot, q0, heatmap = task
    save_heatmap(heatmap, tmp_path / 'h.npz')
    out = tmp_path / 'obs.yaml'
    proc = subprocess.run(
        [sys.executable, '-m', 'advocc_ros.cli', 'attack', '--heatmap', str(tmp_path / 'h.npz'),
         '--scene', 'table_pick', '--budget', '4', '--method', 'task', '--policy', 'solvable',
         '--out', str(out), '--json'], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data['solvable']['verdict'] == 'certified'
    assert data['witness_file'] == str(tmp_path / 'obs.witness.yaml')
    witness = load_witness(data['witness_file'])
    boxes, meta = load_obstacles(out)
    assert meta['solvable']['verdict'] == 'certified' and len(boxes) == 4
    world = CollisionWorld(robot, [sh for o in scene.objects + boxes for sh in o.shapes])
    assert certify(robot, world, scene.goal, witness, q0)[0] is None


def test_attack_config_accepts_the_policy():
    assert AttackConfig(goal_policy='solvable').goal_policy == 'solvable'


def test_tube_samples_surround_the_witness_and_are_valid(task):
    from advocc_ros.attack.objective import tube_samples

    scene, robot, q0, _ = task
    witness = find_witnesses(robot, scene.objects, q0, scene.goal)[0]
    states = witness_states(witness.configurations(robot))
    world = CollisionWorld(robot, scene.shapes)
    Q = tube_samples(world, states, np.random.default_rng(0).normal(0.0, 0.2, (200, robot.nq)))
    assert 100 < len(Q) <= 200  # most perturbations of a free path are free too
    assert not world.collisions_batch(Q).any()
    assert np.all((Q >= robot.lower) & (Q <= robot.upper))
    nearest = np.min(np.linalg.norm(Q[:, None] - states[None], axis=-1), axis=1)
    assert np.median(nearest) < 0.2 * np.sqrt(robot.nq) * 1.5  # around the path, not anywhere
    assert len(tube_samples(world, states, np.zeros((0, robot.nq)))) == 0
