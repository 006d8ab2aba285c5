"""planner_shim with ``backend:=mplib`` as a real process: MPlib answers the plan service
(the orchestrator benchmarks an outside victim through ROS exactly like ours)."""

import json
import signal
import time

import pytest

from conftest import REPO
from test_planner_shim_node import _call, shim_process

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

SCENE = REPO / 'config' / 'scenes' / 'table_pick.yaml'


def test_planner_shim_mplib_backend(ros_env, monkeypatch, table_scene):
    from advocc_msgs.msg import ErrorCodes
    from advocc_msgs.srv import GetInfo, Plan
    from sensor_msgs.msg import JointState

    from advocc_ros.ros.conversions import goal_region_to_msg

    with shim_process(ros_env, monkeypatch, [f'scene_file:={SCENE}', 'backend:=mplib']) as (
            proc, node, executor):
        plan = node.create_client(Plan, '/planner_shim/plan')
        info = node.create_client(GetInfo, '/planner_shim/get_info')
        deadline = time.monotonic() + 60
        while not (plan.wait_for_service(timeout_sec=0.5)
                   and info.wait_for_service(timeout_sec=0.5)):
            assert proc.poll() is None, f'node exited early:\n{proc.stdout.read()}'
            assert time.monotonic() < deadline, 'plan service did not come up within 60 s'
        data = json.loads(_call(node, executor, info, GetInfo.Request(), 10).info_json)
        assert data['backend'] == 'mplib' and data['victims_started'] == ['mplib']
        codes = []
        for seed in range(3):
            req = Plan.Request()
            req.start_state = JointState(name=list(table_scene.start),
                                         position=list(table_scene.start.values()))
            req.goal_region = goal_region_to_msg(table_scene.goal, 'panda_link0')
            req.planner_id = 'rrtconnect'  # ignored: the backend serves every request
            req.time_budget_s, req.seed = 2.0, seed
            res = _call(node, executor, plan, req, 20)
            codes.append(res.error_code.val)
            if res.error_code.val == ErrorCodes.SUCCESS:
                assert len(res.trajectory.points) >= 2
                assert 0 < res.first_solution_s <= 2.0
                assert res.message.startswith('MPlib RRTConnect')
        assert codes.count(ErrorCodes.SUCCESS) >= 2, codes
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
        assert proc.returncode == 0 and 'Traceback' not in out, out
