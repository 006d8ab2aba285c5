"""heatmap_server and attacker as real processes: topics in, obstacles out, bad requests, exits."""

import collections
import dataclasses
import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _start(module, env, *params, sigint_ignored=False):
    """``sigint_ignored``: the node inherits SIGINT ignored, as a shell's background job does."""
    args = [sys.executable, '-m', f'advocc_ros.nodes.{module}', '--ros-args']
    for p in params:
        args += ['-p', p]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, preexec_fn=_ignore_sigint if sigint_ignored else None)


def _stop(proc, timeout_s=15.0):
    """SIGINT, then the exit code (killed and failed if it does not exit in time); a node that
    does not exit with 0 shows the end of its output."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
        pytest.fail(f'{proc.args[2]} ignored SIGINT for {timeout_s} s:\n{_tail(proc)}')
    if code != 0:
        print(f'{proc.args[2]} exited with {code}:\n{_tail(proc)}')
    return code


def _tail(proc, chars=3000) -> str:
    try:
        return (proc.stdout.read() or '')[-chars:] if proc.stdout else ''
    except (OSError, ValueError):
        return ''


def _wait_service(executor, client, proc, timeout_s=60):
    deadline = time.monotonic() + timeout_s
    while not client.service_is_ready():
        assert proc.poll() is None, f'node exited early:\n{proc.stdout.read()}'
        assert time.monotonic() < deadline, f'{client.srv_name} not up within {timeout_s} s'
        executor.spin_once(timeout_sec=0.1)


SENT = collections.Counter()
"""Requests ``_call`` sent per service, resends included."""


def _call(executor, client, request, timeout_s=15, resend_s=5.0):
    """The answer within ``timeout_s``, or the test fails. A request without an answer for
    ``resend_s`` is sent again (then after 2x, 4x, ...; the first answer wins), by
    ``ServiceCalls.call_client``: rmw_fastrtps drops the response to a new client whose reader
    the server has not matched yet, on a loaded machine (test_fuzz_services). The heatmap
    server answers a repeat of an attack from its memo."""
    from advocc_ros.ros.client import ServiceCalls, ServiceError

    calls = ServiceCalls(executor)
    try:
        return calls.call_client(client, request, timeout_s, resend_s=resend_s)
    except ServiceError as exc:
        pytest.fail(str(exc))
    finally:
        SENT.update(calls.sent)


def _request(scene, budget=3, method='ours'):
    from advocc_ros.ros.conversions import attack_request
    return attack_request(scene, budget, method)


def test_attacker_publishes_what_the_core_computes(ros, ros_env, heatmap_file, table_scene,
                                                   panda):
    from advocc_msgs.msg import CollisionObject, GoalRegion, Scene
    from sensor_msgs.msg import JointState
    from visualization_msgs.msg import Marker, MarkerArray

    from advocc_ros.attack import attack
    from advocc_ros.ros.conversions import collision_object_to_msg, goal_region_to_msg
    from advocc_ros.heatmap import load_heatmap
    from advocc_ros.ros.qos import (COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, LATCHED_QOS,
                                    SCENE_TOPIC)
    from advocc_ros.model.pose import Pose
    from advocc_ros.model.scene import make_box

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    attacker = _start('attacker', ros_env, 'budget:=3')
    children += [server, attacker]
    ops, markers = [], []
    node.create_subscription(CollisionObject, COLLISION_OBJECT_TOPIC, ops.append, LATCHED_QOS)
    node.create_subscription(MarkerArray, '/attacker/markers', markers.append, LATCHED_QOS)
    scene_pub = node.create_publisher(Scene, SCENE_TOPIC, LATCHED_QOS)
    goal_pub = node.create_publisher(GoalRegion, GOAL_REGION_TOPIC, LATCHED_QOS)

    msg = Scene(name=table_scene.name)
    msg.header.frame_id = 'panda_link0'
    msg.objects = [collision_object_to_msg(o, 'panda_link0') for o in table_scene.objects]
    msg.start_state = JointState(name=list(table_scene.start),
                                 position=list(table_scene.start.values()))
    scene_pub.publish(msg)
    goal_pub.publish(goal_region_to_msg(table_scene.goal, 'panda_link0'))

    def wait_for(count, timeout_s=60):
        deadline = time.monotonic() + timeout_s
        while len(ops) < count:
            for proc in (server, attacker):
                assert proc.poll() is None, f'{proc.args[2]} exited:\n{proc.stdout.read()}'
            assert time.monotonic() < deadline, f'{len(ops)} of {count} operations arrived'
            executor.spin_once(timeout_sec=0.1)

    wait_for(3)
    q = panda.q_from_names(list(table_scene.start), list(table_scene.start.values()))
    heatmap = load_heatmap(heatmap_file)
    expected = attack(heatmap, panda, table_scene.objects, q, table_scene.goal, 3)
    assert [m.operation for m in ops] == [CollisionObject.ADD] * 3
    assert [m.id for m in ops] == [o.id for o in expected.obstacles]
    for m, obj in zip(ops, expected.obstacles):
        p = m.primitive_poses[0].position
        assert (p.x, p.y, p.z) == pytest.approx(obj.shapes[0].pose.position_m, abs=1e-9)
        assert list(m.primitives[0].dimensions) == pytest.approx([0.05] * 3)
        assert m.header.frame_id == 'panda_link0'
    deadline = time.monotonic() + 10
    while not markers and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
    assert markers[-1].markers[0].action == Marker.DELETEALL
    boxes = [m for m in markers[-1].markers[1:] if m.ns == 'advocc_attack']
    assert [m.type for m in boxes] == [Marker.CUBE] * 3
    scene = [m for m in markers[-1].markers[1:] if m.ns == 'advocc_scene']
    assert sorted(m.text for m in scene) == sorted(o.id for o in table_scene.objects)

    # A new goal: the previous boxes are removed first, then the new ones added.
    goal2 = dataclasses.replace(table_scene.goal, center=Pose(
        (0.55, 0.15, 0.40), table_scene.goal.center.quat_xyzw))
    goal_pub.publish(goal_region_to_msg(goal2, 'panda_link0'))
    wait_for(9)
    assert [(m.operation, m.id) for m in ops[3:6]] == \
        [(CollisionObject.REMOVE, f'adv_{i}') for i in range(3)]
    expected2 = attack(heatmap, panda, table_scene.objects, q, goal2, 3)
    got = [(m.primitive_poses[0].position.x, m.primitive_poses[0].position.y,
            m.primitive_poses[0].position.z) for m in ops[6:9]]
    assert np.allclose(got, expected2.centers_m, atol=1e-9)

    # A new scene with an object where the last box was: new boxes elsewhere.
    blocker = make_box('blocker', expected2.centers_m[-1], (0.06, 0.06, 0.06))
    msg.objects = msg.objects + [collision_object_to_msg(blocker, 'panda_link0')]
    scene_pub.publish(msg)
    wait_for(15)
    assert [(m.operation, m.id) for m in ops[9:12]] == \
        [(CollisionObject.REMOVE, f'adv_{i}') for i in range(3)]
    expected3 = attack(heatmap, panda, table_scene.objects + (blocker,), q, goal2, 3)
    got = [(m.primitive_poses[0].position.x, m.primitive_poses[0].position.y,
            m.primitive_poses[0].position.z) for m in ops[12:15]]
    assert np.allclose(got, expected3.centers_m, atol=1e-9)
    assert not np.allclose(got, expected2.centers_m)

    assert _stop(attacker) == 0
    assert _stop(server) == 0


def test_server_answers_bad_requests_and_keeps_serving(ros, ros_env, heatmap_file,
                                                       table_scene):
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack, GetInfo

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}',
                    'max_budget:=20')
    children.append(server)
    client = node.create_client(Attack, '/heatmap_server/attack')
    _wait_service(executor, client, server)
    sent_before = SENT[client.srv_name]

    good = _call(executor, client, _request(table_scene))
    assert good.error_code.val == ErrorCodes.SUCCESS, good.message
    assert [o.id for o in good.obstacles] == ['adv_0', 'adv_1', 'adv_2']
    assert good.total_mass == pytest.approx(sum(o.covered_mass for o in good.obstacles))
    assert 0 < good.compute_time_s < 5
    assert good.solvable in ('certified', 'goal blocked', 'unknown') and good.solvable_message
    solvable = _request(table_scene, budget=5, method='task')
    solvable.goal_policy = 'solvable'
    kept = _call(executor, client, solvable, timeout_s=60)  # witness search + attack
    assert kept.error_code.val == ErrorCodes.SUCCESS, kept.message
    assert kept.solvable == 'certified', kept.solvable_message  # the witness is kept by design

    def bad(**edit):
        req = _request(table_scene)
        for path, value in edit.items():
            obj, *attrs, last = path.split('__')
            target = req if obj == 'req' else getattr(req, obj)
            for a in attrs:
                target = target[int(a)] if a.isdigit() else getattr(target, a)
            setattr(target, last, value)
        return req

    cases = [
        (bad(req__budget=0), ErrorCodes.INVALID_REQUEST, 'budget'),
        (bad(req__budget=21), ErrorCodes.INVALID_REQUEST, 'budget'),
        (bad(req__method='pfa'), ErrorCodes.UNKNOWN_METHOD, 'pfa'),
        (bad(req__method='nope'), ErrorCodes.UNKNOWN_METHOD, 'nope'),
        (bad(req__box_size=float('nan')), ErrorCodes.INVALID_REQUEST, 'box_size'),
        (bad(req__box_size=-0.05), ErrorCodes.INVALID_REQUEST, 'box size'),  # the core's message
        (bad(goal_region__center__position__x=float('inf')), ErrorCodes.INVALID_REQUEST,
         'goal_region.center.position.x'),
        (bad(scene__0__primitive_poses__0__position__z=float('nan')),
         ErrorCodes.INVALID_REQUEST, 'scene[0].primitive_poses[0].position.z'),
        (bad(start_state__position=[0.0, float('nan'), 0, -2, 0, 1.5, 0.7]),
         ErrorCodes.INVALID_REQUEST, 'start_state.position[1]'),
        (bad(goal_region__position_tolerance=[0.02, -0.01, 0.02]),
         ErrorCodes.INVALID_GOAL_CONSTRAINTS, 'inverted'),
        (bad(goal_region__position_tolerance=[0.0] * 3,
             goal_region__orientation_tolerance=[0.0] * 3),
         ErrorCodes.INVALID_GOAL_CONSTRAINTS, 'empty'),
        (bad(goal_region__link_name='tool0'), ErrorCodes.INVALID_LINK_NAME, 'tool0'),
        (bad(goal_region__header__frame_id='world'), ErrorCodes.INVALID_GOAL_CONSTRAINTS,
         'world'),
        (bad(start_state__name=[f'joint{i}' for i in range(1, 8)]),
         ErrorCodes.INVALID_ROBOT_STATE, 'missing joints'),
        (bad(start_state__position=[0.0, -0.785, 0, -2.356, 0, 1.571, 9.0]),
         ErrorCodes.INVALID_ROBOT_STATE, 'panda_joint7 = 9 not in'),
        # The task check names what collides: a scene pair, a self pair.
        (bad(start_state__position=[0.0, 1.5, 0, -0.2, 0, 1.571, 0.785]),
         ErrorCodes.START_STATE_IN_COLLISION, 'in collision with the scene: panda_'),
        (bad(start_state__position=[0.0, 0.5, 0.0, -3.0, 0.0, 0.5, 0.785]),
         ErrorCodes.START_STATE_IN_COLLISION, 'self collision: panda_link'),
    ]
    for req, code, words in cases:
        res = _call(executor, client, req)
        assert res.error_code.val == code, (words, res.error_code.val, res.message)
        assert words in res.message and not res.obstacles
    # Still serving, same answer as before.
    again = _call(executor, client, _request(table_scene))
    assert again.error_code.val == ErrorCodes.SUCCESS
    assert [o.pose.position.x for o in again.obstacles] == \
        [o.pose.position.x for o in good.obstacles]
    partial = _call(executor, client, _request(table_scene, budget=20))
    assert partial.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL)

    info_client = node.create_client(GetInfo, '/heatmap_server/get_info')
    info = json.loads(_call(executor, info_client, GetInfo.Request()).info_json)
    assert info['robot']['joints'][0] == 'panda_joint1'
    assert info['grid']['voxel_m'] == 0.02 and info['parameters']['max_budget'] == 20
    assert info['requests_served'] == SENT[client.srv_name] - sent_before >= len(cases) + 4

    # The CLI client sees the same server.
    out = subprocess.run([sys.executable, '-m', 'advocc_ros.cli', 'call', 'attack', '--scene',
                          'table_pick', '--budget', '3', '--method', 'ours', '--json',
                          '--timeout', '20'],
                         env=ros_env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert [o['pose']['position'][0] for o in data['obstacles']] == \
        pytest.approx([o.pose.position.x for o in good.obstacles])
    assert data['round_trip_ms'] > 0
    assert _stop(server) == 0


def test_server_answers_a_repeat_without_recomputing(ros, ros_env, heatmap_file, table_scene):
    """A request already answered under the same settings gets the same answer from the
    server's memo (clients resend unanswered requests); another seed or another setting is
    computed; an error is not kept."""
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    children.append(server)
    client = node.create_client(Attack, '/heatmap_server/attack')
    _wait_service(executor, client, server)
    request = _request(table_scene, budget=3, method='random')
    first = _call(executor, client, request)
    again = _call(executor, client, request)
    assert [o.id for o in again.obstacles] == [o.id for o in first.obstacles]
    assert again.compute_time_s == first.compute_time_s  # the first answer, not a new one
    request.seed = 7
    other_seed = _call(executor, client, request)
    set_params = node.create_client(SetParameters, '/heatmap_server/set_parameters')
    _wait_service(executor, set_params, server)
    (result,) = _call(executor, set_params, SetParameters.Request(parameters=[Parameter(
        name='d_min_m', value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                             double_value=0.12))])).results
    assert result.successful, result.reason
    other_setting = _call(executor, client, request)
    assert other_seed.error_code.val == other_setting.error_code.val == first.error_code.val
    request.budget = 0  # an error is answered again, not from the memo
    assert _call(executor, client, request).error_code.val == \
        _call(executor, client, request).error_code.val == ErrorCodes.INVALID_REQUEST
    assert _stop(server) == 0
    log = server.stdout.read()
    assert 'attack #2: the request and settings of attack #1; its answer again' in log, log
    assert [n for n in range(3, 7) if f'attack #{n}: the request' in log] == [], log


def test_server_task_options_are_node_parameters(ros, ros_env, heatmap_file, table_scene):
    """``task_<option>`` parameters set the task method's options; a bad set is refused with
    the reason and the server keeps serving with the options it had."""
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import Attack, GetInfo
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from advocc_ros.attack.task import TaskOptions

    node, executor, children = ros
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}', 'task_detours:=1',
                    'task_tube_rad:=0.3')
    children.append(server)
    client = node.create_client(Attack, '/heatmap_server/attack')
    info_client = node.create_client(GetInfo, '/heatmap_server/get_info')
    set_client = node.create_client(SetParameters, '/heatmap_server/set_parameters')
    _wait_service(executor, client, server)
    request = _request(table_scene, budget=3, method='task')
    request.goal_policy = 'solvable'

    def attack_stats():
        res = _call(executor, client, request, timeout_s=90)  # the first: the witness search
        assert res.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL), res.message
        info = json.loads(_call(executor, info_client, GetInfo.Request()).info_json)
        return info['last_attack_stats'], info['task_options']

    def set_one(name, value):
        kind = (ParameterType.PARAMETER_INTEGER if isinstance(value, int)
                else ParameterType.PARAMETER_DOUBLE)
        req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=kind, integer_value=value if isinstance(value, int) else 0,
            double_value=float(value)))])
        (result,) = _call(executor, set_client, req).results
        return result

    stats, options = attack_stats()
    assert options['detours'] == 1 and options['tube_rad'] == 0.3
    assert options['approach_points'] == TaskOptions.approach_points
    approaches = stats['task_approach_samples']
    negative = set_one('task_detours', -1)
    assert not negative.successful and 'detours must be an integer >= 0, got -1' in \
        negative.reason
    rad = set_one('task_tube_rad', float('nan'))
    assert not rad.successful and 'tube_rad must be a finite number >= 0' in rad.reason
    typed = set_one('task_detours', 2.5)
    assert not typed.successful and 'type' in typed.reason.lower()
    stats, options = attack_stats()  # still serving, with the options it had
    assert options['detours'] == 1 and stats['task_approach_samples'] == approaches
    assert set_one('task_tube_samples', 0).successful
    assert attack_stats()[1]['tube_samples'] == 0
    assert _stop(server) == 0


def test_server_refuses_a_corrupted_heatmap(ros_env, tmp_path):
    path = tmp_path / 'broken.npz'
    path.write_bytes(b'PK\x03\x04 this is not a heatmap')
    proc = _start('heatmap_server', ros_env, f'heatmap_file:={path}')
    try:
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 1
    assert 'cannot start' in out and 'not a readable heatmap file' in out and str(path) in out


def test_run_attack_nodes_for_the_demo(ros_env, monkeypatch, heatmap_file, table_scene,
                                       tmp_path):
    from advocc_ros.attack import load_obstacles
    from advocc_ros.ros.feeder import run_attack_nodes

    monkeypatch.setenv('ROS_LOCALHOST_ONLY', ros_env['ROS_LOCALHOST_ONLY'])
    out = tmp_path / 'obstacles.yaml'
    bag = tmp_path / 'attack.mcap'
    report = run_attack_nodes(heatmap_file, table_scene, out, budget=2,
                              domain=int(ros_env['ROS_DOMAIN_ID']), timeout_s=60, bag=bag)
    assert report['exit_codes'] == {'heatmap_server': 0, 'attacker': 0}
    objects, meta = load_obstacles(out)
    assert [o.id for o in objects] == ['adv_0', 'adv_1'] and meta['budget'] == 2
    _check_attack_bag(bag, table_scene, objects)


def _check_attack_bag(bag, scene, boxes):
    """The attacker's bag reads back, message for message, as what the core converts the
    scene, goal and boxes into (stamps aside: the bag's are its own)."""
    import importlib

    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    from advocc_ros.ros.bag import attack_messages

    with open(bag, 'rb') as stream:
        records = [(c.topic, s.name, m) for s, c, m in make_reader(stream).iter_messages()]
    expected = attack_messages(scene, boxes)
    assert [r[0] for r in records] == [t for t, _ in expected] + ['/heatmap_server/heatmap']
    for (topic, type_name, message), (_, want) in zip(records, expected):
        package, _, name = type_name.split('/')
        got = deserialize_message(message.data,
                                  getattr(importlib.import_module(f'{package}.msg'), name))
        if topic == '/attacker/markers':  # the node's scene went through messages once more
            assert [(m.ns, m.id, m.type) for m in got.markers] == \
                [(m.ns, m.id, m.type) for m in want.markers]
            for a, b in zip(got.markers, want.markers):
                o, p = a.pose.orientation, b.pose.orientation
                assert (o.x, o.y, o.z, o.w) == pytest.approx((p.x, p.y, p.z, p.w), abs=1e-9)
                assert a.pose.position == b.pose.position
            continue
        got.header.stamp = want.header.stamp
        assert got == want, topic


@pytest.mark.parametrize('after_s', [0.5, 1.0, 2.0, 3.5, 5.0, 8.0])
def test_sigint_at_any_moment_stops_the_server_cleanly(ros_env, heatmap_file, after_s):
    """Ctrl-C while the node imports its libraries, builds itself, just after its executor
    starts or while it idles: a clean stop within the stop timeout (rclpy's races there hung
    it or gave exit 1 with a traceback; a Ctrl-C swallowed by an import hung it)."""
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}')
    time.sleep(after_s)
    assert _stop(server) in (0, -signal.SIGINT)


@pytest.mark.parametrize('after_s', [0.5, 3.5])
def test_a_node_started_with_sigint_ignored_stops_on_it(ros_env, heatmap_file, after_s):
    """Started from a shell's background job (``advocc bench ... &``), a node inherits SIGINT
    ignored: the orchestrator's SIGINT must still stop it, in its imports as after rclpy.init."""
    server = _start('heatmap_server', ros_env, f'heatmap_file:={heatmap_file}',
                    sigint_ignored=True)
    time.sleep(after_s)
    assert _stop(server) in (0, -signal.SIGINT)
