"""ROS 2 nodes: thin shells over the core. ``run`` is their shared ``main`` body."""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading

SPIN_WAKE_S = 0.5
"""Longest wait of the spin loop before it looks at the context again [s]."""

SHUTDOWN_LIMIT_S = 30.0
"""Longest a node may take from leaving its spin (or failing to start) to its process's end;
past it the process prints where it is stuck and exits 1 [s]."""

_SIGINT_SEEN = threading.Event()


def _remember_sigint(signum, frame):
    """Python's own Ctrl-C (KeyboardInterrupt), remembered: trimesh's optional imports catch
    BaseException, so a Ctrl-C during a node's imports raised an exception nobody saw and the
    node then served on as if nothing had happened."""
    _SIGINT_SEEN.set()
    raise KeyboardInterrupt


def _die_by_sigint_after_a_swallowed_one(exc_type, exc, tb):
    """An import that swallowed the KeyboardInterrupt can fail later on what it left half done
    (trimesh: a TypeError on the ``ExceptionWrapper`` standing in for ``Path3D``, exit 1 with
    that traceback). After a Ctrl-C, die by SIGINT instead, as Python does on Ctrl-C."""
    if not _SIGINT_SEEN.is_set():
        return sys.__excepthook__(exc_type, exc, tb)
    sys.stdout.flush()
    sys.stderr.flush()
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGINT)


# Installed when this package is imported, i.e. before a node module's own (slow) imports;
# rclpy's handler, installed later, passes SIGINT on to it. Also over an inherited SIG_IGN (a
# shell starts background jobs so): rclpy.init stops the node on SIGINT all the same, and a
# Ctrl-C during the imports must not be the one that is lost.
if threading.current_thread() is threading.main_thread() \
        and signal.getsignal(signal.SIGINT) in (signal.default_int_handler, signal.SIG_IGN):
    signal.signal(signal.SIGINT, _remember_sigint)
    if sys.excepthook is sys.__excepthook__:
        sys.excepthook = _die_by_sigint_after_a_swallowed_one


def _interrupted(rclpy) -> bool:
    """Whether a Ctrl-C (or an external shutdown) has happened in this process."""
    return _SIGINT_SEEN.is_set() or not rclpy.ok()


def run(node_class, name: str, args=None, startup_errors: tuple = (), threads: int = 1) -> int:
    """Spin one node and always shut down cleanly.

    An exception of ``startup_errors`` raised while constructing the node (a bad file or
    parameter), or a parameter override that its descriptor or on-set check refuses, is logged
    as ``cannot start: ...`` and gives exit code 1; Ctrl-C and an external shutdown give 0.
    ``threads > 1`` spins a ``MultiThreadedExecutor`` (callbacks in reentrant groups can then
    run while another one waits).
    """
    from advocc_ros.ros.spawn import die_with_parent

    if _SIGINT_SEEN.is_set():  # Ctrl-C during the imports, swallowed on the way
        return 0
    die_with_parent()  # before rclpy starts its threads
    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import (ExternalShutdownException, MultiThreadedExecutor,
                                 SingleThreadedExecutor)

    rclpy.init(args=args)
    # Bound before its __init__ runs, so that a constructor raising after rclpy's Node.__init__
    # leaves no half-built node to the interpreter's teardown, where its destruction can hang
    # the exit (rclpy destroys a node's parts eagerly for the same reason; docs/design.md).
    node = node_class.__new__(node_class)
    try:
        try:
            node.__init__()
        except (ParameterException, *startup_errors) as exc:
            if _interrupted(rclpy):  # the error is the Ctrl-C's doing (see below)
                return 0
            rclpy.logging.get_logger(name).fatal(f'cannot start: {exc}')
            return 1
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 \
            else SingleThreadedExecutor()
        executor.add_node(node)
        # Not executor.spin(): a SIGINT that lands before the executor's wait set exists wakes
        # nothing, and an endless wait then ignores it (measured: 2 of 28 stops hung). A bounded
        # wait sees the shut-down context within SPIN_WAKE_S.
        while rclpy.ok() and not _SIGINT_SEEN.is_set():
            executor.spin_once(timeout_sec=SPIN_WAKE_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if not _interrupted(rclpy):
            raise
        # Ctrl-C shut the context down under a call that needed it (the constructor, a wait
        # set being built: rclpy raises RCLError there), or its KeyboardInterrupt was raised
        # inside Python called from C++ and came out as a SystemError: a clean stop all the same.
    finally:
        # Armed for the rest of the process (module teardown included): a stuck DDS shutdown
        # must not leave a node that never exits. A C thread, so it fires under a held GIL too.
        faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
        if hasattr(node, '_type_description_service'):  # Node.__init__ ran to its last line
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
