"""The planner shims of one scene over ROS: node processes, their ``~/plan`` and
``~/get_info`` clients, and the collision objects injected on ``/advocc/collision_object``.

Implements :class:`advocc_ros.orchestrator.shims.ShimPool` for the run loop.
"""

from __future__ import annotations

import json
import logging
import pathlib
import time
from typing import Any

from advocc_ros.bench.protocol import BenchConfig, BenchError
from advocc_ros.orchestrator.shims import CallFailed, PlanAnswer, PlanJob, Shim, ShimState
from advocc_ros.ros.spawn import Child, node_name

log = logging.getLogger(__name__)

_SYNC_POLL_S = 0.2


class _Handles:
    """A shim's ROS side: its process (None: external), clients and calls in flight."""

    def __init__(self, child: Child | None, plan, info):
        self.child, self.plan, self.info = child, plan, info
        self.future: Any = None
        self.info_future: Any = None
        self.info_at = 0.0


class RosShimPool:
    """``cfg.shims`` planner_shim processes for ``scene`` (plus external ones if configured)."""

    def __init__(self, graph, cfg: BenchConfig, scene, scene_file: pathlib.Path, robot,
                 env: dict, log_dir: pathlib.Path, children: list[Child]):
        self.graph, self.cfg, self.scene, self.robot = graph, cfg, scene, robot
        self.children = children
        self.expected: dict[str, Any] = {}  # id -> SceneObject of the current injection
        self.shims: list[Shim] = []
        stem = node_name(pathlib.Path(scene_file).stem)
        for i in range(cfg.shims):
            child = Child(f'advocc_shim_{stem}_{i}', 'planner_shim',
                          {'scene_file': str(scene_file)}, env, log_dir)
            child.start()
            children.append(child)
            self.shims.append(self._make_shim(f'/{child.name}', child))

    def _make_shim(self, name: str, child: Child | None) -> Shim:
        from advocc_msgs.srv import GetInfo, Plan
        handles = _Handles(child, self.graph.client(Plan, f'{name}/plan'),
                           self.graph.client(GetInfo, f'{name}/get_info'))
        return Shim(name, external=child is None, since=time.monotonic(), handles=handles)

    def discover(self, wait: bool = False) -> None:
        if not self.cfg.external_shims:
            return
        known = {s.name for s in self.shims}
        if wait:  # DDS discovery takes a moment; wait longer when nobody else would plan
            deadline = time.monotonic() + (3.0 if self.cfg.shims else 30.0)
            found: list[str] = []
            while time.monotonic() < deadline and not (found and not self.cfg.shims):
                self.graph.spin(0.1)
                found = [n for n in self.graph.plan_services() if n not in known]
        else:
            found = [n for n in self.graph.plan_services() if n not in known]
        for name in found:
            log.info('external shim %s', name)
            self.shims.append(self._make_shim(name, None))

    def spin(self, timeout_s: float) -> None:
        self.graph.spin(timeout_s)

    # -- processes ---------------------------------------------------------------------------

    def exit_code(self, shim: Shim) -> int | None:
        child = shim.handles.child
        return None if child is None else child.exit_code()

    def output(self, shim: Shim) -> str:
        child = shim.handles.child
        return child.tail() if child is not None else ''

    def _forget(self, shim: Shim) -> None:
        h = shim.handles
        if h.future is not None:
            h.plan.remove_pending_request(h.future)
        h.future = h.info_future = None
        self.graph.drop(h.plan)
        self.graph.drop(h.info)

    def drop(self, shim: Shim) -> None:
        self._forget(shim)
        shim.state = ShimState.DEAD

    def restart(self, shim: Shim) -> None:
        self._forget(shim)
        child = shim.handles.child
        child.restart()
        shim.handles = self._make_shim(shim.name, child).handles
        shim.state, shim.since = ShimState.STARTING, time.monotonic()

    def close(self) -> None:
        self._publish_remove_all()
        for shim in self.shims:
            child = shim.handles.child
            if child is not None:
                child.stop()
                if child in self.children:
                    self.children.remove(child)
            self.graph.drop(shim.handles.plan)
            self.graph.drop(shim.handles.info)

    # -- injection ---------------------------------------------------------------------------

    def _publish(self, obj, operation) -> None:
        from advocc_ros.ros.conversions import collision_object_to_msg
        self.graph.publish(collision_object_to_msg(obj, self.scene.frame, operation))

    def _publish_remove_all(self) -> None:
        from advocc_ros.model.scene import Operation, SceneObject
        self._publish(SceneObject('', ()), Operation.REMOVE)

    def inject(self, objects: tuple) -> None:
        """REMOVE every injected object, ADD the attack's boxes; every shim must re-sync."""
        from advocc_ros.model.scene import Operation
        self._publish_remove_all()
        for obj in objects:
            self._publish(obj, Operation.ADD)
        self.expected = {o.id: o for o in objects}
        for shim in self.shims:
            if shim.state in (ShimState.IDLE, ShimState.SYNC):
                shim.state, shim.since = ShimState.SYNC, time.monotonic()

    def _check_info(self, info: dict) -> str | None:
        """Why a shim answering ``info`` cannot serve the scene (None: it can)."""
        static = sorted(o.id for o in self.scene.objects)
        if info.get('scene') != self.scene.name or sorted(info.get('static_objects', [])) \
                != static:
            return (f'holds scene {info.get("scene")!r} with {info.get("static_objects")}, '
                    f'not {self.scene.name!r}')
        return None

    def _step_info(self, shim: Shim, now: float) -> dict | None:
        """Poll ``get_info`` without blocking; the answer when one arrived."""
        from advocc_msgs.srv import GetInfo
        h = shim.handles
        if h.info_future is not None:
            if not h.info_future.done():
                if now - h.info_at > 5.0:
                    h.info.remove_pending_request(h.info_future)
                    h.info_future = None
                return None
            future, h.info_future = h.info_future, None
            try:
                res = future.result()
                return json.loads(res.info_json) if res.success else None
            except Exception:  # noqa: BLE001 - a failed call is retried
                return None
        if now - h.info_at >= _SYNC_POLL_S and h.info.service_is_ready():
            h.info_future = self.graph.send(h.info, GetInfo.Request())
            h.info_at = now
        return None

    def sync(self, shim: Shim, now: float) -> str | None:
        info = self._step_info(shim, now)
        if shim.state == ShimState.STARTING:
            if info is not None:
                why = self._check_info(info)
                if why is None:
                    shim.state, shim.since = ShimState.SYNC, now
                elif shim.external:
                    log.info('external shim %s %s: not used', shim.name, why)
                    shim.state = ShimState.DEAD
                else:
                    raise BenchError(f'{shim.name} {why}')
            elif now - shim.since > self.cfg.start_timeout_s:
                if shim.external:
                    shim.state = ShimState.DEAD
                else:
                    return 'did not come up'
            return None
        if info is not None:
            self._sync(shim, info, now)
        return None

    def _sync(self, shim: Shim, info: dict, now: float) -> None:
        """Idle once the shim's injected objects are exactly the current attack's."""
        from advocc_ros.model.scene import Operation, SceneObject
        have = set(info.get('injected_objects', []))
        want = set(self.expected)
        if have == want:
            shim.state = ShimState.IDLE
            return
        if now - shim.since > 2.0:  # latched history should have done it: repair
            for obj_id in sorted(have - want):
                self._publish(SceneObject(obj_id, ()), Operation.REMOVE)
            for obj_id in sorted(want - have):
                self._publish(self.expected[obj_id], Operation.ADD)  # ADD replaces: harmless
            shim.since = now
            log.info('%s re-synced: had %s, want %s', shim.name, sorted(have), sorted(want))

    # -- plans -------------------------------------------------------------------------------

    def plan(self, shim: Shim, job: PlanJob) -> None:
        from advocc_ros.ros.conversions import plan_request
        req = plan_request(self.robot, job.q_start, job.goal, self.scene.frame, job.planner_id,
                           job.time_budget_s, job.seed)
        shim.handles.future = self.graph.send(shim.handles.plan, req)

    def poll(self, shim: Shim) -> PlanAnswer | None:
        from advocc_ros.ros.conversions import trajectory_from_msg
        from advocc_ros.ros.errors import code_name

        future = shim.handles.future
        if future is None or not future.done():
            return None
        shim.handles.future = None
        try:
            res = future.result()
        except Exception as exc:  # noqa: BLE001 - the loop runs the trial again
            raise CallFailed(str(exc)) from exc
        status = code_name(res.error_code.val)
        path = trajectory_from_msg(self.robot, res.trajectory) if status == 'SUCCESS' else None
        return PlanAnswer(status, int(res.error_code.val), res.message,
                          float(res.planning_time_s), len(res.trajectory.points), path,
                          float(res.first_solution_s) if status == 'SUCCESS' else None)
