"""``Planner.set_scene`` from one thread while another plans: the planner's lock orders them."""

import threading
import time

import pytest

pytestmark = [pytest.mark.processes, pytest.mark.timing]  # a worker; PRM* timed against a sleep


def test_set_scene_waits_for_the_request_in_flight(table_scene):
    """PRM* plans for its whole budget; a scene change meanwhile takes effect after it."""
    from advocc_ros.model.scene import make_box
    from advocc_ros.planning.worker import Planner
    from advocc_ros.kinematics.ik import start_configuration

    with Planner(table_scene).start() as planner:
        q0 = start_configuration(table_scene, planner.robot)
        finished = []

        def plan():
            res = planner.plan(q0, table_scene.goal, 'prmstar', 1.5, 0)
            finished.append(time.monotonic())
            return res

        thread = threading.Thread(target=plan)
        thread.start()
        time.sleep(0.5)
        walled = table_scene.with_objects([make_box('wall', (2.0, 2.0, 2.0), (0.1, 0.1, 0.1))])
        planner.set_scene(walled)
        changed = time.monotonic()
        thread.join(30)
        assert finished and changed >= finished[0]
        assert planner.scene is walled
