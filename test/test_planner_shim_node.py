"""planner_shim as a real process: plan, inject a wall on the topic, bad requests, an internal
error, clean exit."""

import contextlib
import json
import math
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

SCENE = REPO / 'config' / 'scenes' / 'table_pick.yaml'
FAULT_SEED = 77
"""The shim's planning worker raises on this seed (``ADVOCC_PLANNING_FAULT``)."""


@pytest.fixture
def ros(ros_env, monkeypatch):
    """rclpy in this process on the child's domain; the shim node as a child process."""
    with shim_process(ros_env, monkeypatch, [f'scene_file:={SCENE}', 'watchdog_margin_s:=2.0'],
                      {'ADVOCC_PLANNING_FAULT': f'raise:{FAULT_SEED}'}) as handles:
        yield handles


@contextlib.contextmanager
def shim_process(ros_env, monkeypatch, params: list[str], env: dict | None = None):
    """A planner_shim child with ``params`` (``name:=value``) and extra ``env``, and an rclpy
    node of this process on its domain: yields (process, node, executor); always stops both."""
    import rclpy

    for key in ('ROS_DOMAIN_ID', 'ROS_LOCALHOST_ONLY'):
        monkeypatch.setenv(key, ros_env[key])
    args = [a for p in params for a in ('-p', p)]
    proc = subprocess.Popen(
        [sys.executable, '-m', 'advocc_ros.nodes.planner_shim', '--ros-args', *args],
        env=dict(ros_env, **(env or {})), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('shim_test_client', context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield proc, node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
        if proc.stdout is not None and not proc.stdout.closed:
            print('planner_shim output:\n' + proc.stdout.read())  # shown when a test fails


def _call(node, executor, client, request, timeout_s):
    future = client.call_async(request)
    executor.spin_until_future_complete(future, timeout_sec=timeout_s)
    assert future.done(), f'no answer within {timeout_s} s'
    return future.result()


def _wall_over_goal(goal):
    """A closed box around the goal region as one collision object (4 walls + roof)."""
    from advocc_msgs.msg import CollisionObject
    from geometry_msgs.msg import Pose
    from shape_msgs.msg import SolidPrimitive

    cx, cy, _ = goal.center.position_m
    msg = CollisionObject(id='cage', operation=CollisionObject.ADD)
    msg.header.frame_id = 'panda_link0'
    msg.pose.orientation.w = 1.0
    inner, t, zl, zh = 0.09, 0.02, 0.10, 0.62
    h, zc, off, outer = zh - zl, (zl + zh) / 2, inner + t / 2, inner + t
    for (x, y, z), dims in [((cx + off, cy, zc), (t, 2 * outer, h)),
                            ((cx - off, cy, zc), (t, 2 * outer, h)),
                            ((cx, cy + off, zc), (2 * inner, t, h)),
                            ((cx, cy - off, zc), (2 * inner, t, h)),
                            ((cx, cy, zh + t / 2), (2 * outer, 2 * outer, t))]:
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = x, y, z
        pose.orientation.w = 1.0
        msg.primitives.append(SolidPrimitive(type=SolidPrimitive.BOX, dimensions=list(dims)))
        msg.primitive_poses.append(pose)
    return msg


def test_planner_shim_end_to_end(ros, table_scene):
    from advocc_msgs.msg import CollisionObject, ErrorCodes
    from advocc_msgs.srv import GetInfo, Plan
    from sensor_msgs.msg import JointState

    from advocc_ros.ros.conversions import goal_region_to_msg
    from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, LATCHED_QOS

    proc, node, executor = ros
    plan = node.create_client(Plan, '/planner_shim/plan')
    info = node.create_client(GetInfo, '/planner_shim/get_info')
    deadline = time.monotonic() + 60
    while not (plan.wait_for_service(timeout_sec=0.5) and info.wait_for_service(timeout_sec=0.5)):
        assert proc.poll() is None, f'node exited early:\n{proc.stdout.read()}'
        assert time.monotonic() < deadline, 'plan service did not come up within 60 s'

    def request(**changes):
        req = Plan.Request()
        req.start_state = JointState(name=list(table_scene.start),
                                     position=list(table_scene.start.values()))
        req.goal_region = goal_region_to_msg(table_scene.goal, 'panda_link0')
        req.planner_id = 'rrtconnect'
        req.time_budget_s = 1.0
        for key, value in changes.items():
            setattr(req, key, value)
        return req

    # 1. Plans in the static scene (several seeds: sampling planners are random).
    codes = []
    for seed in range(3):
        res = _call(node, executor, plan, request(seed=seed), 10)
        codes.append(res.error_code.val)
        if res.error_code.val == ErrorCodes.SUCCESS:
            assert len(res.trajectory.points) >= 2
            assert res.trajectory.joint_names[0] == 'panda_joint1'
            # budget 1 s; MoveIt-style simplification may add a little on a loaded machine
            assert 0 < res.planning_time_s < 1.0 + 2.0
            assert 0 < res.first_solution_s <= res.planning_time_s
    assert codes.count(ErrorCodes.SUCCESS) >= 2, codes

    # 2. A cage injected on the topic walls in the goal: the outcome changes.
    pub = node.create_publisher(CollisionObject, COLLISION_OBJECT_TOPIC, LATCHED_QOS)
    pub.publish(_wall_over_goal(table_scene.goal))
    deadline = time.monotonic() + 20
    while True:
        data = json.loads(_call(node, executor, info, GetInfo.Request(), 10).info_json)
        if data['injected_objects'] == ['cage']:
            break
        assert time.monotonic() < deadline, f'cage never arrived: {data}'
        time.sleep(0.2)
    assert 'table' in data['static_objects']
    res = _call(node, executor, plan, request(seed=0), 10)
    assert res.error_code.val in (ErrorCodes.GOAL_IN_COLLISION, ErrorCodes.TIMED_OUT,
                                  ErrorCodes.PLANNING_FAILED), res.message
    assert len(res.trajectory.points) == 0

    # Removing it restores success.
    pub.publish(CollisionObject(id='cage', operation=CollisionObject.REMOVE))
    deadline = time.monotonic() + 20
    while json.loads(_call(node, executor, info, GetInfo.Request(), 10).info_json)[
            'injected_objects']:
        assert time.monotonic() < deadline
        time.sleep(0.2)
    res = _call(node, executor, plan, request(seed=1), 10)
    assert res.error_code.val == ErrorCodes.SUCCESS, res.message

    # 3. Bad requests get clear codes; the node keeps serving.
    nan_state = JointState(name=list(table_scene.start),
                           position=[math.nan] + list(table_scene.start.values())[1:])
    wrong_names = JointState(name=[f'j{i}' for i in range(7)], position=[0.0] * 7)
    inverted = goal_region_to_msg(table_scene.goal, 'panda_link0')
    inverted.position_tolerance = [-0.01, 0.02, 0.02]
    start = dict(table_scene.start)
    outside = JointState(name=list(start), position=list(dict(start, panda_joint4=0.5).values()))
    on_table = JointState(name=list(start), position=[0.0, 1.5, 0, -0.2, 0, 1.571, 0.785])
    bad = [
        # An invalid task is refused with the reason: the joint, the colliding pair.
        (request(start_state=outside), ErrorCodes.INVALID_ROBOT_STATE,
         'panda_joint4 = 0.5 not in'),
        (request(start_state=on_table), ErrorCodes.START_STATE_IN_COLLISION,
         'in collision with the scene: panda_'),
        (request(planner_id='no_such_planner'), ErrorCodes.UNKNOWN_METHOD, 'unknown planner'),
        (request(start_state=nan_state), ErrorCodes.INVALID_REQUEST, 'non-finite'),
        (request(start_state=wrong_names), ErrorCodes.INVALID_ROBOT_STATE, 'missing joints'),
        (request(time_budget_s=-1.0), ErrorCodes.INVALID_REQUEST, 'time_budget_s'),
        (request(goal_region=inverted), ErrorCodes.INVALID_GOAL_CONSTRAINTS, '>= 0'),
    ]
    for req, code, words in bad:
        res = _call(node, executor, plan, req, 10)
        assert res.error_code.val == code, res.message
        assert words in res.message, res.message
    # An exception in the worker is an internal error on the wire, not a planning failure.
    from advocc_ros.planning.types import PlanStatus
    res = _call(node, executor, plan, request(seed=FAULT_SEED), 10)
    assert res.error_code.val == PlanStatus.INTERNAL_ERROR, res.message
    assert 'fault injected' in res.message and len(res.trajectory.points) == 0
    # 3b. A bad parameter value at run time is refused with the core's (PlanningConfig) message.
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    params = node.create_client(SetParameters, '/planner_shim/set_parameters')
    assert params.wait_for_service(timeout_sec=10)

    def set_double(name, value):
        req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
        return _call(node, executor, params, req, 10).results[0]

    refused = set_double('time_budget_s', -1.0)
    assert not refused.successful and 'planning parameter time_budget_s' in refused.reason
    assert set_double('time_budget_s', 2.0).successful
    res = _call(node, executor, plan, request(seed=2, planner_id='bkpiece1'), 10)
    assert res.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.TIMED_OUT), res.message
    data = json.loads(_call(node, executor, info, GetInfo.Request(), 10).info_json)
    assert data['worker_restarts'] == 0 and data['requests_served'] >= 10
    # 3c. An OMPL 2 victim by name: AORRTC plans in its own venv's worker, started on first use
    # (2.0.1 refuses its own solution where start and goal connect directly: planning failed).
    res = _call(node, executor, plan, request(seed=3, planner_id='aorrtc'), 60)
    assert res.error_code.val in (ErrorCodes.SUCCESS, ErrorCodes.PLANNING_FAILED,
                                  ErrorCodes.TIMED_OUT), res.message
    assert 'AORRTC' in res.message, res.message

    # 4. SIGINT: clean exit, worker gone.
    worker_pid = data['worker_pid']
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
    with pytest.raises(ProcessLookupError):
        import os
        os.kill(worker_pid, 0)
