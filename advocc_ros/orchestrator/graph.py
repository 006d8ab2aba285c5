"""The orchestrator's ROS graph: one rclpy context, node, executor and publisher."""

from __future__ import annotations

import os
import time

from advocc_ros.orchestrator.shims import CallFailed


class Graph:
    """The orchestrator's rclpy context, node, executor and collision-object publisher."""

    def __init__(self, domain: int | None):
        import rclpy
        from advocc_msgs.msg import CollisionObject
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from advocc_ros.ros.qos import COLLISION_OBJECT_TOPIC, LATCHED_QOS

        self._rclpy = rclpy
        self.context = rclpy.Context()
        # Our own SIGINT/SIGTERM handling: rclpy's would shut the context down under us.
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f'advocc_orchestrator_{os.getpid()}',
                                      context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.publisher = self.node.create_publisher(CollisionObject, COLLISION_OBJECT_TOPIC,
                                                    LATCHED_QOS)

    def spin(self, timeout_s: float = 0.02) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def client(self, srv_type, service: str):
        return self.node.create_client(srv_type, service)

    def drop(self, client) -> None:
        if client is not None:
            self.node.destroy_client(client)

    def call(self, client, request, timeout_s: float, alive=lambda: True):
        """Blocking call that keeps spinning; ``CallFailed`` on timeout or a dead server."""
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline or not alive():
                raise CallFailed(f'{client.srv_name} is not available')
            self.spin(0.05)
        future = client.call_async(request)
        while not future.done():
            if time.monotonic() > deadline or not alive():
                client.remove_pending_request(future)
                raise CallFailed(f'{client.srv_name}: no answer within {timeout_s:g} s'
                                 if alive() else f'{client.srv_name}: the node died')
            self.spin(0.05)
        if future.exception() is not None:
            raise CallFailed(f'{client.srv_name}: {future.exception()}')
        return future.result()

    def plan_services(self) -> list[str]:
        """Node names (``/ns/name``) serving an advocc Plan service on this domain."""
        return sorted(name[:-len('/plan')] for name, types in
                      self.node.get_service_names_and_types()
                      if name.endswith('/plan') and 'advocc_msgs/srv/Plan' in types)

    def close(self) -> None:
        try:
            self.executor.shutdown()
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.context)
