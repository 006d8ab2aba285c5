"""The orchestrator's SIGINT/SIGTERM: an ``Interrupted`` raised where it is safe."""

from __future__ import annotations

import contextlib
import signal


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT): stop children, keep finished trials."""


class SignalGate:
    """Raises ``Interrupted`` on a signal, except inside ``held()`` blocks, after which it does.

    Held around rclpy calls (an exception raised inside a message conversion, Python called
    from C++, came out as a ``SystemError`` and the run ended with exit 1, not 'interrupted')
    and around a record's append (between the durable write and the store's update it left
    the summary a trial short of the file).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self._holding = False
        self._held: int | None = None

    def on_signal(self, signum, frame) -> None:
        if self._holding:
            self._held = signum
            return
        raise Interrupted(f'signal {signal.Signals(signum).name}')

    @contextlib.contextmanager
    def held(self):
        if self._holding:  # nested: the outer block raises
            yield
            return
        self._holding = True
        try:
            yield
        finally:
            self._holding = False
        if self._held is not None:
            signum, self._held = self._held, None
            raise Interrupted(f'signal {signal.Signals(signum).name}')


__all__ = ['Interrupted', 'SignalGate']
