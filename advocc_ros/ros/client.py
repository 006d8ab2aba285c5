"""One rclpy context, node and executor for calling services from a plain program."""

from __future__ import annotations

import os
import time


class ServiceError(OSError):
    """A service is not available, did not answer in time, or the call failed."""


class ServiceClient:
    """Calls services with ``call_async`` + futures on its own context (never a blocking call)."""

    def __init__(self, name: str = 'advocc_call'):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f'{name}_{os.getpid()}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict = {}

    def client(self, srv_type, service: str, timeout_s: float):
        """A ready client for ``service``, or ``ServiceError`` after ``timeout_s``."""
        if service not in self._clients:
            self._clients[service] = self.node.create_client(srv_type, service)
        client = self._clients[service]
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise ServiceError(f'service {service} is not available after {timeout_s:g} s '
                                   '(is the node running, on this ROS_DOMAIN_ID?)')
            self.executor.spin_once(timeout_sec=0.05)
        return client

    def call(self, srv_type, service: str, request, timeout_s: float):
        """The response, or ``ServiceError`` when there is none within ``timeout_s``."""
        client = self.client(srv_type, service, timeout_s)
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        if not future.done():
            client.remove_pending_request(future)
            raise ServiceError(f'{service}: no answer within {timeout_s:g} s')
        if future.exception() is not None:
            raise ServiceError(f'{service}: call failed ({future.exception()})')
        return future.result()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'ServiceClient':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ['ServiceClient', 'ServiceError']
