"""The attacker node's timeout path against a real service that holds its requests: the
request is abandoned after ``timeout_s``, old boxes are removed, the task is asked again, and a
late answer to the abandoned request is ignored."""

import time

import pytest

from test_attack_nodes import _start, _stop

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def test_a_server_that_never_answers_times_out_and_is_asked_again(
        ros, ros_env, table_scene):  # noqa: F811
    import rclpy
    from advocc_msgs.msg import CollisionObject, ErrorCodes, GoalRegion, Obstacle, Scene
    from advocc_msgs.srv import Attack

    from advocc_ros.ros.conversions import goal_region_to_msg, joint_state_from_dict
    from advocc_ros.ros.qos import (COLLISION_OBJECT_TOPIC, GOAL_REGION_TOPIC, LATCHED_QOS,
                                    SCENE_TOPIC)

    node, executor, children = ros
    held = []  # (arrival time, future that releases the answer)

    async def hold(request, response):
        release = rclpy.task.Future(executor=executor)
        held.append((time.monotonic(), release))
        await release
        response.error_code.val = ErrorCodes.SUCCESS
        box = Obstacle(id=f'late_{len(held)}', size=[0.05, 0.05, 0.05])
        box.pose.orientation.w = 1.0
        response.obstacles = [box]
        return response

    # Reentrant: a held request must not keep the next one (or our subscription) waiting.
    node.create_service(Attack, '/fake_server/attack', hold,
                        callback_group=rclpy.callback_groups.ReentrantCallbackGroup())
    ops = []
    node.create_subscription(CollisionObject, COLLISION_OBJECT_TOPIC, ops.append, LATCHED_QOS)
    timeout_s = 2.0
    attacker = _start('attacker', ros_env, 'server:=/fake_server', f'timeout_s:={timeout_s}')
    children.append(attacker)
    msg = Scene(name=table_scene.name, start_state=joint_state_from_dict(table_scene.start))
    msg.header.frame_id = 'panda_link0'
    node.create_publisher(Scene, SCENE_TOPIC, LATCHED_QOS).publish(msg)
    node.create_publisher(GoalRegion, GOAL_REGION_TOPIC, LATCHED_QOS).publish(
        goal_region_to_msg(table_scene.goal, 'panda_link0'))

    def spin_until(done, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        while not done():
            assert attacker.poll() is None, f'attacker exited:\n{attacker.stdout.read()}'
            if time.monotonic() > deadline:
                attacker.kill()
                raise AssertionError(f'no {what} within {timeout_s} s ({len(held)} requests '
                                     f'held):\n{attacker.communicate()[0]}')
            executor.spin_once(timeout_sec=0.05)

    spin_until(lambda: len(held) >= 2, 90, 'second request')
    gap = held[1][0] - held[0][0]
    assert timeout_s <= gap < timeout_s + 5, gap  # abandoned at the timeout, then asked again
    held[0][1].set_result(None)  # the abandoned request answers late: ignored
    held[1][1].set_result(None)  # the current one answers: its box is placed
    spin_until(lambda: any(op.operation == CollisionObject.ADD for op in ops), 30, 'box')
    assert [op.id for op in ops if op.operation == CollisionObject.ADD] == ['late_2']
    assert _stop(attacker) == 0
    log = attacker.stdout.read()
    assert log.count('attack request timed out') >= 1, log
