"""Node parameters: one source of defaults (the node's PARAMETERS), descriptors that rclpy
enforces on a running node, and config files that say the same."""

import dataclasses
import re
import subprocess
import sys
import time

import pytest
import yaml

from conftest import REPO

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def _yaml(node):
    data = yaml.safe_load((REPO / 'config' / f'{node}.yaml').read_text())
    return data[f'/{node}']['ros__parameters']


@pytest.mark.parametrize('node', ['attacker', 'heatmap_server', 'planner_shim'])
def test_config_files_say_what_the_nodes_declare(node):
    import importlib

    from advocc_ros.ros.params import defaults

    params = importlib.import_module(f'advocc_ros.nodes.{node}').PARAMETERS
    declared = defaults(params)
    in_file = _yaml(node)
    assert set(in_file) <= set(declared), set(in_file) - set(declared)
    for name, value in in_file.items():
        assert value == declared[name], name
    commented = {'allowed_dirs'}  # documented as a comment: its default is computed
    assert set(declared) - set(in_file) <= commented
    for p in params:
        assert p.description, p.name


def test_attacker_methods_are_the_ones_a_server_runs():
    from advocc_ros.attack.methods import REGISTRY, SERVER_METHODS
    from advocc_ros.nodes.attacker import PARAMETERS

    assert set(SERVER_METHODS) == {n for n, s in REGISTRY.items() if not s.queries_planner}
    assert 'task' in SERVER_METHODS and 'pfa' not in SERVER_METHODS
    line = next(line for line in (REPO / 'config' / 'attacker.yaml').read_text().splitlines()
                if line.strip().startswith('method:'))
    listed = re.search(r'#\s*([\w+ |]+?)\s*\(', line).group(1).split(' | ')
    assert listed == list(SERVER_METHODS), line
    method = next(p for p in PARAMETERS if p.name == 'method')
    assert str(list(SERVER_METHODS)) in method.constraints


def test_every_attack_setting_is_described_on_the_server():
    from advocc_ros.attack import AttackConfig
    from advocc_ros.nodes.heatmap_server import PARAMETERS

    described = {p.name: p.description for p in PARAMETERS}
    for field in dataclasses.fields(AttackConfig):
        assert not described[field.name].startswith('AttackConfig.'), \
            f'{field.name}: add its description to heatmap_server._CONFIG_DOC'


def _set(proc, calls, **values):
    """The results of one set_parameters call on the running attacker (resent when it goes
    unanswered: a set is the same twice); the attacker's output when it never answers."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from advocc_ros.ros.client import ServiceError

    def value(v):
        if isinstance(v, int):
            return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=v)
        if isinstance(v, float):
            return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v)
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=v)
    req = SetParameters.Request(parameters=[Parameter(name=k, value=value(v))
                                            for k, v in values.items()])
    try:
        client = calls.client(SetParameters, '/attacker/set_parameters', 60.0)
        return calls.call_client(client, req, 30.0, lambda: proc.poll() is None,
                                 resend_s=2.0).results
    except ServiceError as exc:
        proc.kill()
        pytest.fail(f'{exc} (attacker exit code {proc.wait(10)}); its output:\n'
                    f'{proc.stdout.read()[-3000:]}')


def test_running_attacker_refuses_bad_sets_with_the_reason(ros_env, monkeypatch):
    from rcl_interfaces.srv import DescribeParameters

    from advocc_ros.ros.client import ServiceClient

    monkeypatch.setenv('ROS_LOCALHOST_ONLY', ros_env['ROS_LOCALHOST_ONLY'])
    proc = subprocess.Popen([sys.executable, '-m', 'advocc_ros.nodes.attacker'], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with ServiceClient('parameter_test', domain_id=int(ros_env['ROS_DOMAIN_ID'])) as calls:
            (low,) = _set(proc, calls, budget=0)
            assert not low.successful and 'budget out of range' in low.reason
            assert 'Min: 1, Max: 100' in low.reason
            (wide,) = _set(proc, calls, box_size_m=-0.1)
            assert not wide.successful and 'box_size_m out of range' in wide.reason
            (fixed,) = _set(proc, calls, server='/elsewhere')
            assert not fixed.successful and 'read-only' in fixed.reason
            (pfa,) = _set(proc, calls, method='pfa')
            assert not pfa.successful and "'task'" in pfa.reason
            (typed,) = _set(proc, calls, budget=2.5)
            assert not typed.successful and 'type' in typed.reason.lower()
            assert all(r.successful for r in _set(proc, calls, budget=5, method='task'))

            described = calls.call(DescribeParameters, '/attacker/describe_parameters',
                                   DescribeParameters.Request(names=['budget', 'server']),
                                   30.0, resend_s=2.0)
            budget, server = described.descriptors
            assert budget.description and budget.integer_range[0].to_value == 100
            assert server.read_only
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def test_out_of_range_override_stops_the_node_with_the_reason(ros_env):
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, '-m', 'advocc_ros.nodes.attacker', '--ros-args',
                           '-p', 'timeout_s:=-1.0'], env=ros_env, capture_output=True,
                          text=True, timeout=60)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    assert 'cannot start' in out and 'timeout_s out of range' in out
    assert 'Traceback' not in out and time.monotonic() - t0 < 60
