"""Export of tasks as MotionBenchMaker problems: the files mean what MoveIt reads in them, and our
own importer gives back the same task (collision verdicts, goal region, locked joints)."""

import dataclasses
import json
import pathlib

import numpy as np
import pinocchio as pin
import pytest
import yaml

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import goal_configuration, start_configuration
from advocc_ros.formats.mbm_scene import load_mbm_scene
from advocc_ros.formats.mbm_export import load_trajectory, problem_files, write_problem
from advocc_ros.model.robot import load_robot
from advocc_ros.model.pose import Pose, SceneError
from advocc_ros.model.scene import SceneObject, load_scene, make_box
from advocc_ros.model.shapes import Shape

from conftest import REPO

FAMILIES = REPO / 'test' / 'data' / 'mbm' / 'families'


def assert_same_task(original, imported, states: np.ndarray):
    """Same robot (locked joints), start, goal region and collision verdicts on ``states``."""
    robot_a, robot_b = load_robot(original.robot), load_robot(imported.robot)
    assert robot_b.hash == robot_a.hash
    assert robot_b.locked_values == pytest.approx(robot_a.locked_values)
    q_a, q_b = start_configuration(original, robot_a), start_configuration(imported, robot_b)
    assert q_b == pytest.approx(q_a, abs=1e-12)
    ga, gb = original.goal, imported.goal
    assert gb.link == ga.link
    assert gb.center.position_m == pytest.approx(ga.center.position_m, abs=1e-9)
    R_a, R_b = ga.center.to_se3().rotation, gb.center.to_se3().rotation
    assert np.linalg.norm(pin.log3(R_a.T @ R_b)) < 1e-9
    assert gb.position_tolerance_m == pytest.approx(ga.position_tolerance_m, abs=1e-12)
    assert gb.orientation_tolerance_rad == pytest.approx(ga.orientation_tolerance_rad,
                                                         abs=1e-12)
    assert gb.tool_offset.position_m == pytest.approx(ga.tool_offset.position_m, abs=1e-12)
    assert gb.seed_joints == ga.seed_joints
    assert np.allclose(gb.seeds, ga.seeds, atol=1e-12)
    verdict_a = CollisionWorld(robot_a, original.shapes).collisions_batch(states)
    verdict_b = CollisionWorld(robot_b, imported.shapes).collisions_batch(states)
    assert np.array_equal(verdict_a, verdict_b)
    inside_a = [ga.contains(robot_a.ee_pose(q) * ga.tool_offset.to_se3()) for q in states]
    inside_b = [gb.contains(robot_b.ee_pose(q) * gb.tool_offset.to_se3()) for q in states]
    assert inside_a == inside_b
    return verdict_a


def _probe_states(robot, q_init, q_goal, rng, n=200):
    """A straight path start -> goal, states near it and uniform ones: some collide."""
    line = q_init + np.linspace(0, 1, 60)[:, None] * (q_goal - q_init)
    near = line[rng.integers(0, len(line), n)] + rng.normal(0, 0.2, (n, robot.nq))
    return np.vstack([line, np.clip(near, robot.lower, robot.upper), robot.sample_q(rng, n)])


@pytest.fixture(scope='module')
def attacked(table_scene):
    """table_pick with three boxes (one in the way of a straight path) and that path."""
    robot = load_robot(table_scene.robot)
    q_init = start_configuration(table_scene, robot)
    q_goal = goal_configuration(robot, table_scene.goal, q_init)
    assert q_goal is not None
    boxes = (make_box('adv_0', (0.45, 0.0, 0.55), (0.08,) * 3),
             make_box('adv_1', (0.3, 0.3, 0.4), (0.08,) * 3),
             SceneObject('adv_2', (Shape('box', (0.05, 0.1, 0.05), Pose(
                 (0.6, -0.25, 0.3), (0.0, 0.0, 0.3826834, 0.9238795))),)))
    path = np.array([q_init, 0.5 * (q_init + q_goal), q_goal])
    return table_scene.with_objects(boxes), robot, path


def test_round_trip_gives_the_same_task(attacked, tmp_path):
    scene, robot, path = attacked
    files = write_problem(tmp_path, 1, scene, robot, robot.joint_names, path)
    assert files == problem_files(tmp_path, 1)
    assert [f.name for f in files.__dict__.values()] == [
        'scene0001.yaml', 'request0001.yaml', 'trajectory0001.yaml']
    imported = load_mbm_scene(files.scene, files.request)
    assert sorted(o.id for o in imported.objects) == sorted(o.id for o in scene.objects)
    rng = np.random.default_rng(3)
    verdicts = assert_same_task(scene, imported, _probe_states(robot, path[0], path[-1], rng))
    assert verdicts.any() and not verdicts.all()  # the probe sees both verdicts
    names, waypoints = load_trajectory(files.trajectory)
    assert names == robot.joint_names
    assert np.array_equal(waypoints, path)


def test_files_mean_what_moveit_reads(attacked, tmp_path):
    """MoveIt's semantics, applied to the written request, agree with our region: the tool
    point inside the constraint box (in the box's frame) and the rotation vector of
    ``R_goal^T R_link`` within the per-axis tolerances."""
    scene, robot, path = attacked
    files = write_problem(tmp_path, 7, scene, robot, robot.joint_names, path)
    request = yaml.safe_load(files.request.read_text())
    goal = request['goal_constraints'][0]
    pc, oc = goal['position_constraints'][0], goal['orientation_constraints'][0]
    assert request['goal_constraints'][1:] == []  # table_pick's region has no seeds
    assert oc['parameterization'] == 1 and pc['link_name'] == oc['link_name'] == 'panda_hand'

    def xyz(d, keys='xyz'):
        return np.array([d[k] for k in keys])

    box = pc['constraint_region']['primitives'][0]
    assert box['type'] == 1
    pose = pc['constraint_region']['primitive_poses'][0]
    T_box = pin.XYZQUATToSE3(np.r_[xyz(pose['position']), xyz(pose['orientation'], 'xyzw')])
    R_goal = pin.Quaternion(*np.roll(xyz(oc['orientation'], 'xyzw'), 1)).matrix()
    tol = np.array([oc[f'absolute_{a}_axis_tolerance'] for a in 'xyz'])
    rng = np.random.default_rng(0)
    q_goal = path[-1]
    states = np.vstack([q_goal + rng.normal(0, s, (150, robot.nq)) for s in (0.01, 0.05, 0.2)])
    inside_ours, inside_moveit = [], []
    for q in states:
        T_link = robot.ee_pose(q)
        point = T_link.act(xyz(pc['target_point_offset']))
        in_box = np.all(np.abs(T_box.actInv(point)) <= 0.5 * np.array(box['dimensions']) + 1e-9)
        in_rot = np.all(np.abs(pin.log3(R_goal.T @ T_link.rotation)) <= tol + 1e-9)
        inside_moveit.append(bool(in_box and in_rot))
        inside_ours.append(scene.goal.contains(T_link * scene.goal.tool_offset.to_se3()))
    assert inside_ours == inside_moveit
    assert 0 < sum(inside_ours) < len(states)
    state = request['start_state']['joint_state']
    assert state['name'][-2:] == ['panda_finger_joint1', 'panda_finger_joint2']
    traj = yaml.safe_load(files.trajectory.read_text())['joint_trajectory']
    times = [p['time_from_start']['sec'] + 1e-9 * p['time_from_start']['nanosec']
             for p in traj['points']]
    assert times[0] == 0 and all(b > a for a, b in zip(times, times[1:]))
    slowest = np.max(np.abs(path[1] - path[0]) / robot.model.velocityLimit)
    assert times[1] == pytest.approx(slowest, abs=1e-8)


def test_a_joint_goal_problem_keeps_its_seed_and_fingers(tmp_path):
    """A MotionBenchMaker problem with a joint goal (fingers at 0.065 -> 0.04) comes back
    with the same region, seed and locked fingers."""
    family = FAMILIES / 'table_pick'
    scene = load_mbm_scene(family / 'scene0001.yaml', family / 'request0001.yaml')
    assert scene.goal.seeds
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    q_goal = np.array(scene.goal.seeds[0])
    files = write_problem(tmp_path, 1, scene, robot, robot.joint_names,
                          np.array([q_init, q_goal]))
    imported = load_mbm_scene(files.scene, files.request)
    assert robot.locked_values == pytest.approx({'panda_finger_joint1': 0.04,
                                                 'panda_finger_joint2': 0.04})
    assert_same_task(scene, imported, _probe_states(robot, q_init, q_goal,
                                                    np.random.default_rng(1)))


def test_what_cannot_be_exported_is_a_clear_error(attacked, tmp_path):
    scene, robot, path = attacked
    ur5 = load_scene(REPO / 'config' / 'scenes' / 'ur5_table.yaml')
    with pytest.raises(SceneError, match='only the default Panda'):
        write_problem(tmp_path, 1, ur5, load_robot(ur5.robot), (), path)
    turned = dataclasses.replace(scene, goal=dataclasses.replace(
        scene.goal, tool_offset=Pose((0, 0, 0.1), (0.0, 0.0, 0.7071068, 0.7071068))))
    with pytest.raises(SceneError, match='tool_offset has a rotation'):
        write_problem(tmp_path, 1, turned, robot, robot.joint_names, path)
    cloud = scene.with_objects([SceneObject('points', (Shape(
        'cloud', (0.02,), Pose(), vertices=np.zeros((4, 3))),))])
    with pytest.raises(SceneError, match='point-cloud objects'):
        write_problem(tmp_path, 1, cloud, robot, robot.joint_names, path)
    with pytest.raises(SceneError, match='planned joints'):
        write_problem(tmp_path, 1, scene, robot, robot.joint_names[:6], path[:, :6])
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize('text,match', [
    ('[1, 2]', 'expected a mapping'),
    ('joint_trajectory: {joint_names: [a], points: []}', 'no points'),
    ('joint_trajectory: {joint_names: [a, b], points: [{positions: [1.0]}]}', '1 values for 2'),
    ('joint_trajectory: {joint_names: [a], points: [{positions: [.nan]}]}', 'positions'),
    ('joint_trajectory: {joint_names: [3], points: [{positions: [1.0]}]}', 'joint names'),
])
def test_bad_trajectory_files_are_clear_errors(tmp_path, text, match):
    path = pathlib.Path(tmp_path) / 'trajectory0001.yaml'
    path.write_text(text)
    with pytest.raises(SceneError, match=match):
        load_trajectory(path)


# ---------------------------------------------------------------------------------------------
# `advocc export` on a real attack under the solvable policy


@pytest.fixture(scope='module')
def solvable_attack(tmp_path_factory, table_scene):
    """``advocc attack --policy solvable`` on table_pick: obstacles file, witness beside it."""
    from advocc_ros.cli import main
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap

    folder = tmp_path_factory.mktemp('attack')
    heatmap = folder / 'table_pick.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=2000), seed=1), heatmap)
    obstacles = folder / 'obs.yaml'
    assert main(['attack', '--heatmap', str(heatmap), '--scene', 'table_pick', '--budget', '3',
                 '--method', 'task', '--policy', 'solvable', '--out', str(obstacles)]) == 0
    return obstacles


def _witness_of(files, robot):
    from advocc_ros.planning.witness import Witness

    names, waypoints = load_trajectory(files.trajectory)
    return Witness(joint_names=names, waypoints=waypoints, locked=dict(robot.locked_values),
                   source={})


@pytest.mark.processes
def test_export_round_trip_keeps_the_witness_valid(solvable_attack, table_scene, tmp_path,
                                                   capsys):
    from advocc_ros.attack import load_obstacles
    from advocc_ros.planning.witness import certify
    from advocc_ros.cli import main
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.planning.witness import load_witness, witness_file, witness_states

    out = tmp_path / 'mbm'
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--out', str(out)]) == 0
    files = problem_files(out, 1)
    imported = load_any_scene(files.scene, files.request)
    boxes, _ = load_obstacles(solvable_attack)
    original = table_scene.with_objects(boxes)
    robot = load_robot(imported.robot)
    witness = load_witness(witness_file(solvable_attack))
    states = witness_states(witness.configurations(robot))
    rng = np.random.default_rng(5)
    probe = _probe_states(robot, states[0], states[-1], rng)
    verdicts = assert_same_task(original, imported, np.vstack([states, probe]))
    assert not verdicts[:len(states)].any() and verdicts[len(states):].any()
    world = CollisionWorld(robot, imported.shapes)
    q_init = start_configuration(imported, robot)  # the request's start: the witness's first
    assert certify(robot, world, imported.goal, _witness_of(files, robot), q_init)[0] is None
    assert np.array_equal(_witness_of(files, robot).waypoints, witness.configurations(robot))
    # the checker can fail: the witness without its last waypoint misses the goal region
    short = dataclasses.replace(witness, waypoints=witness.waypoints[:-1])
    assert certify(robot, world, imported.goal, short, q_init)[0] is not None

    capsys.readouterr()
    assert main(['evaluate', '--scene', str(files.scene), '--request', str(files.request),
                 '--trials', '1', '--time', '2', '--json']) == 0
    row = json.loads(capsys.readouterr().out)
    assert row['objects'] == len(original.objects) and len(row['records']) == row['trials'] == 1


@pytest.mark.processes
def test_export_refuses_what_it_cannot_vouch_for(solvable_attack, tmp_path, capsys):
    from advocc_ros.cli import main
    from advocc_ros.planning.witness import load_witness, save_witness, witness_file

    out = tmp_path / 'mbm'
    missing = tmp_path / 'none.witness.yaml'
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--witness', str(missing), '--out', str(out)]) == 2
    assert 'no witness file' in capsys.readouterr().err
    # another task's goal: the witness does not end in the box scene's region
    assert main(['export', '--scene', 'box', '--obstacles', str(solvable_attack),
                 '--out', str(out)]) == 2
    assert 'not a solution' in capsys.readouterr().err
    assert not out.exists() or not list(out.iterdir())
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--out', str(out)]) == 0
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--out', str(out)]) == 2
    assert 'already holds problem files' in capsys.readouterr().err
    # a witness made with other finger values is another robot's path
    witness = load_witness(witness_file(solvable_attack))
    other = tmp_path / 'other.witness.yaml'
    save_witness(other, dataclasses.replace(witness, locked={
        j: v + 0.01 for j, v in witness.locked.items()}))
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--witness', str(other), '--out', str(tmp_path / 'other')]) == 2
    assert 'locked joint' in capsys.readouterr().err
    # variations need a heatmap to attack with, and enough draws
    data = yaml.safe_load(solvable_attack.read_text())
    data.pop('heatmap_file')
    bare = tmp_path / 'bare.yaml'
    bare.write_text(yaml.safe_dump(data))
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(bare), '--out',
                 str(tmp_path / 'v'), '--variations', '2']) == 2
    assert 'give --heatmap' in capsys.readouterr().err
    data['method'] = 'pfa'
    bare.write_text(yaml.safe_dump(data))
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(bare), '--heatmap',
                 str(solvable_attack), '--out', str(tmp_path / 'v'), '--variations', '2']) == 2
    assert "method 'pfa'" in capsys.readouterr().err
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--out', str(tmp_path / 'v'), '--variations', '3', '--max-draws', '2']) == 2
    assert '--max-draws must be' in capsys.readouterr().err


@pytest.mark.processes
def test_variations_are_attacked_again_and_certified(solvable_attack, tmp_path):
    from advocc_ros.planning.witness import certify
    from advocc_ros.cli import main
    from advocc_ros.formats.mbm_scene import load_any_scene

    out = tmp_path / 'dataset'
    assert main(['export', '--scene', 'table_pick', '--obstacles', str(solvable_attack),
                 '--out', str(out), '--variations', '2', '--seed', '3',
                 '--task-option', 'detours=1']) == 0
    manifest = yaml.safe_load((out / 'export.yaml').read_text())
    assert [p['scene'] for p in manifest['problems']] == ['scene0001.yaml', 'scene0002.yaml']
    assert manifest['goal_policy'] == 'solvable'
    # --task-option replaces the obstacles file's options (those of its own attack: 2 detours)
    assert yaml.safe_load(solvable_attack.read_text())['task_options']['detours'] == 2
    assert manifest['task_options']['detours'] == 1
    centres = []
    for k, entry in enumerate(manifest['problems'], 1):
        files = problem_files(out, k)
        scene = load_any_scene(files.scene, files.request)
        robot = load_robot(scene.robot)
        assert certify(robot, CollisionWorld(robot, scene.shapes), scene.goal,
                       _witness_of(files, robot), start_configuration(scene, robot))[0] is None
        assert entry['boxes'] and all(b in {o.id for o in scene.objects} for b in entry['boxes'])
        centres.append(scene.goal.center.position_m)
    assert not np.allclose(centres[0], centres[1])  # the target (and its goal) moved
