"""The orchestrator's ROS graph: a ``ServiceClient`` (one rclpy context, node and executor) and
the collision-object publisher."""

from __future__ import annotations

import contextlib
from typing import Callable, ContextManager

from advocc_ros.orchestrator.shims import CallFailed


class Graph:
    """The orchestrator's rclpy context, node, executor and collision-object publisher."""

    def __init__(self, domain: int | None,
                 guard: Callable[[], ContextManager] = contextlib.nullcontext):
        from advocc_msgs.msg import CollisionObject

        from advocc_ros.ros.client import ServiceClient
        from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, LATCHED_QOS

        # Our own SIGINT/SIGTERM handling: rclpy's would shut the context down under us.
        # ``guard`` holds them around rclpy calls (see ServiceClient).
        self._calls = ServiceClient('advocc_orchestrator', domain_id=domain,
                                    handle_signals=False, guard=guard)
        self.node = self._calls.node
        self.publisher = self.node.create_publisher(CollisionObject, COLLISION_OBJECT_TOPIC,
                                                    LATCHED_QOS)

    def spin(self, timeout_s: float = 0.02) -> None:
        self._calls.spin(timeout_s)

    def send(self, client, request):
        """The future of ``client``'s answer to ``request`` (sent under the guard)."""
        return self._calls.send(client, request)

    def publish(self, msg) -> None:
        with self._calls.guard():
            self.publisher.publish(msg)

    def client(self, srv_type, service: str):
        return self.node.create_client(srv_type, service)

    def drop(self, client) -> None:
        if client is not None:
            self.node.destroy_client(client)

    def call(self, client, request, timeout_s: float, alive=lambda: True,
             resend_s: float | None = None):
        """Blocking call that keeps spinning; ``CallFailed`` on timeout or a dead server
        (``resend_s``: see ``ServiceClient.call_client``)."""
        from advocc_ros.ros.client import ServiceError
        try:
            return self._calls.call_client(client, request, timeout_s, alive, resend_s)
        except ServiceError as exc:
            raise CallFailed(str(exc)) from None

    def plan_services(self) -> list[str]:
        """Node names (``/ns/name``) serving an advocc Plan service on this domain."""
        return sorted(name[:-len('/plan')] for name, types in
                      self.node.get_service_names_and_types()
                      if name.endswith('/plan') and 'advocc_msgs/srv/Plan' in types)

    def close(self) -> None:
        self._calls.close()
