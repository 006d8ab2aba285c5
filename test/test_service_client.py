"""``ServiceClient``: a call that gets no answer is sent again when asked (``resend_s``), the
first answer wins; without it the call fails with ``ServiceError`` at its timeout. A program
whose signal handler raises (the orchestrator) holds signals around rclpy calls (``guard``).

A lost response (Fast DDS drops it when the server has not matched the new client's response
reader within 100 ms) cannot be caused on demand, so the server here holds its first request
for longer than the call's timeout: to the client that is the same silence."""

import os
import signal
import threading
import time

import pytest


@pytest.fixture
def slow_first_server(ros_env, monkeypatch):
    """A real Trigger service on the test's domain whose first request is answered only
    after 20 s; every later one at once. Yields the service name and the requests seen."""
    import rclpy
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from std_srvs.srv import Trigger

    monkeypatch.setenv('ROS_DOMAIN_ID', ros_env['ROS_DOMAIN_ID'])
    monkeypatch.setenv('ROS_LOCALHOST_ONLY', ros_env['ROS_LOCALHOST_ONLY'])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('slow_first_server', context=context)
    seen = []
    release = threading.Event()

    def answer(request, response):
        seen.append(time.monotonic())
        if len(seen) == 1:
            release.wait(20.0)
        response.success, response.message = True, f'answer to request {len(seen)}'
        return response

    node.create_service(Trigger, '/slow_first/trigger', answer,
                        callback_group=ReentrantCallbackGroup())
    executor = MultiThreadedExecutor(num_threads=3, context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield '/slow_first/trigger', seen
    finally:
        release.set()
        rclpy.try_shutdown(context=context)
        thread.join(25)


def test_an_unanswered_request_is_sent_again_and_the_first_answer_wins(slow_first_server):
    from std_srvs.srv import Trigger

    from advocc_ros.ros.client import ServiceClient

    name, seen = slow_first_server
    with ServiceClient('resend_test') as client:
        t0 = time.monotonic()
        res = client.call(Trigger, name, Trigger.Request(), timeout_s=15.0, resend_s=1.0)
        elapsed = time.monotonic() - t0
    assert res.success and res.message == 'answer to request 2'
    assert len(seen) == 2 and elapsed < 10.0, (len(seen), elapsed)
    assert seen[1] - seen[0] >= 0.9  # resent after resend_s, not at once


def test_without_resend_a_silent_server_is_a_timeout(slow_first_server):
    from std_srvs.srv import Trigger

    from advocc_ros.ros.client import ServiceClient, ServiceError

    name, seen = slow_first_server
    with ServiceClient('no_resend_test') as client:
        t0 = time.monotonic()
        with pytest.raises(ServiceError, match='no answer within 3 s'):
            client.call(Trigger, name, Trigger.Request(), timeout_s=3.0)
        assert time.monotonic() - t0 < 10.0
    assert len(seen) == 1


def test_a_signal_during_a_response_conversion_interrupts_the_orchestrator_after_it(
        slow_first_server, ros_env, tmp_path):
    """The orchestrator's SIGINT handler raises; raised inside rclpy's conversion of a response
    (Python code called from C++) it came out as a SystemError and the run ended with exit 1
    instead of 'interrupted'. Held by the orchestrator's guard, it interrupts after the spin."""
    from std_srvs.srv import Trigger

    from advocc_ros.bench import BenchConfig
    from advocc_ros.orchestrator.graph import Graph
    from advocc_ros.orchestrator.run import Orchestrator
    from advocc_ros.orchestrator.signals import Interrupted

    name, seen = slow_first_server
    orch = Orchestrator(BenchConfig(), tmp_path / 'run')
    graph = Graph(int(ros_env['ROS_DOMAIN_ID']), orch.signals.held)
    client = graph.client(Trigger, name)
    graph.call(client, Trigger.Request(), 15.0, resend_s=1.0)  # the server's slow first one
    converted = []
    original_init = Trigger.Response.__init__

    def init_then_sigint(self, **kwargs):
        original_init(self, **kwargs)
        if threading.current_thread() is threading.main_thread():  # the client's side
            converted.append(self)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)  # the handler runs here, inside the conversion

    old = signal.signal(signal.SIGINT, orch.signals.on_signal)
    Trigger.Response.__init__ = init_then_sigint
    try:
        with pytest.raises(Interrupted):
            graph.call(client, Trigger.Request(), 15.0)
        assert converted
    finally:
        Trigger.Response.__init__ = original_init
        signal.signal(signal.SIGINT, old)
        graph.close()
