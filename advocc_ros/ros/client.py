"""Calling services from a plain program: through an executor it is given (``ServiceCalls``, the
tests' own node), or on one rclpy context, node and executor of its own (``ServiceClient``)."""

from __future__ import annotations

import collections
import contextlib
import os
import time
from typing import Callable, ContextManager


class ServiceError(OSError):
    """A service is not available, did not answer in time, or the call failed."""


class ServiceCalls:
    """Calls services with ``call_async`` + futures through an executor it is given (never a
    blocking call), spinning it meanwhile; ``sent`` counts the requests sent per service,
    resends included. ``node`` (needed by ``client`` and ``call`` only) makes the clients.

    ``guard``: a context manager entered around every rclpy call that runs Python code from C++
    (spinning, sending): a program whose signal handler raises holds its signals there, since
    an exception raised inside a message conversion comes out as a ``SystemError``.
    """

    def __init__(self, executor, node=None,
                 guard: Callable[[], ContextManager] = contextlib.nullcontext):
        self.executor, self.node, self.guard = executor, node, guard
        self._clients: dict = {}
        self.sent: collections.Counter = collections.Counter()

    def spin(self, timeout_s: float = 0.05) -> None:
        with self.guard():
            self.executor.spin_once(timeout_sec=timeout_s)

    def send(self, client, request):
        """``client.call_async(request)`` under the guard: the future of the answer."""
        self.sent[client.srv_name] += 1
        with self.guard():
            return client.call_async(request)

    def client(self, srv_type, service: str, timeout_s: float):
        """A ready client for ``service``, or ``ServiceError`` after ``timeout_s``."""
        if service not in self._clients:
            self._clients[service] = self.node.create_client(srv_type, service)
        client = self._clients[service]
        self.wait_ready(client, timeout_s)
        return client

    def wait_ready(self, client, timeout_s: float, alive: Callable[[], bool] = lambda: True
                   ) -> None:
        """Spin until ``client``'s service is ready; ``ServiceError`` after ``timeout_s`` or
        once ``alive()`` says the server died."""
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline or not alive():
                raise ServiceError(f'service {client.srv_name} is not available after '
                                   f'{timeout_s:g} s (is the node running, on this '
                                   'ROS_DOMAIN_ID?)')
            self.spin(0.05)

    def call_client(self, client, request, timeout_s: float,
                    alive: Callable[[], bool] = lambda: True, resend_s: float | None = None):
        """The response of ``client`` within ``timeout_s`` (waiting for the service included),
        or ``ServiceError``; spins meanwhile, so other callbacks keep running.

        ``resend_s``: send the request again when it has had no answer for ``resend_s``, and
        again after 2x, 4x, ... that long; the first answer wins. rmw_fastrtps drops a
        response when the server has not matched this client's response reader within 100 ms
        (a new client's first call, on a busy machine): the call would then wait for nothing.
        Only for requests that give the same answer twice (an attack for a seed, info, a
        parameter set).
        """
        deadline = time.monotonic() + timeout_s
        self.wait_ready(client, timeout_s, alive)
        futures = [self.send(client, request)]
        interval = resend_s
        resend_at = time.monotonic() + resend_s if resend_s else float('inf')
        while not any(f.done() for f in futures):
            now = time.monotonic()
            if now > deadline or not alive():
                for future in futures:
                    client.remove_pending_request(future)
                raise ServiceError(f'{client.srv_name}: no answer within {timeout_s:g} s'
                                   if alive() else f'{client.srv_name}: the node died')
            if now >= resend_at:
                futures.append(self.send(client, request))
                interval *= 2
                resend_at = now + interval
            self.spin(0.05)
        future = next(f for f in futures if f.done())
        for other in futures:
            if other is not future:
                client.remove_pending_request(other)
        if future.exception() is not None:
            raise ServiceError(f'{client.srv_name}: call failed ({future.exception()})')
        return future.result()

    def call(self, srv_type, service: str, request, timeout_s: float,
             resend_s: float | None = None):
        """The response, or ``ServiceError`` when there is none within ``timeout_s``
        (``resend_s``: as in ``call_client``)."""
        client = self.client(srv_type, service, timeout_s)
        return self.call_client(client, request, timeout_s, resend_s=resend_s)


class ServiceClient(ServiceCalls):
    """``ServiceCalls`` on one rclpy context, node and executor of its own, for a plain program.

    ``domain_id``: the ROS domain (None: ``ROS_DOMAIN_ID``); ``handle_signals=False`` leaves
    SIGINT/SIGTERM to the program (rclpy's handlers would shut the context down under it).
    """

    def __init__(self, name: str = 'advocc_call', domain_id: int | None = None,
                 handle_signals: bool = True,
                 guard: Callable[[], ContextManager] = contextlib.nullcontext):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=None if handle_signals else SignalHandlerOptions.NO)
        node = rclpy.create_node(f'{name}_{os.getpid()}', context=self.context)
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(node)
        super().__init__(executor, node, guard)

    def close(self) -> None:
        try:
            self.executor.shutdown()
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'ServiceClient':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ['ServiceCalls', 'ServiceClient', 'ServiceError']
