"""advocc_ros.nodes.run, the body of every node's main: each way a node's process ends (a
Ctrl-C at an awkward moment, a constructor that fails) ends it, with the right code."""

import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


_SWALLOW_CTRL_C = (
    'try:\n'
    '    os.kill(os.getpid(), signal.SIGINT)\n'
    '    time.sleep(1.0)\n'
    'except BaseException:\n'
    '    pass  # as trimesh\'s optional imports do\n')


def _python_with_a_swallowed_ctrl_c(env, before: str, after: str, indent: str = '',
                                    timeout_s: float = 60):
    """Run ``before``, a Ctrl-C that an ``except BaseException`` swallows (indented by
    ``indent``), then ``after``, in a fresh Python; the finished process."""
    import textwrap
    code = ('import os, signal, time\n' + before + textwrap.indent(_SWALLOW_CTRL_C, indent)
            + after)
    return subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=timeout_s)


def test_an_import_broken_by_a_swallowed_ctrl_c_dies_by_sigint_without_a_traceback(ros_env):
    """trimesh, having swallowed the KeyboardInterrupt, fails a few lines later with a
    TypeError (measured: 1 of 60 heatmap_server stops). That is the Ctrl-C's doing: the
    process dies by SIGINT, as on any Ctrl-C during Python's imports, not with exit 1."""
    proc = _python_with_a_swallowed_ctrl_c(
        ros_env, 'import advocc_ros.nodes\n',
        'raise TypeError("unsupported operand type(s) for |")\n')
    assert proc.returncode == -signal.SIGINT, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    ok = subprocess.run([sys.executable, '-c', 'import advocc_ros.nodes\nraise TypeError("x")'],
                        env=ros_env, capture_output=True, text=True, timeout=60)
    assert ok.returncode == 1 and 'TypeError: x' in ok.stderr  # no Ctrl-C: the usual traceback


def test_an_error_that_a_ctrl_c_caused_while_the_node_builds_is_a_clean_stop(ros_env):
    """A Ctrl-C during construction can surface as some other error (a SystemError out of C++,
    a file load that failed half-way): exit 0, not 'cannot start' and exit 1."""
    proc = _python_with_a_swallowed_ctrl_c(
        ros_env,
        'from rclpy.node import Node\n'
        'from advocc_ros.nodes import run\n'
        'class Built(Node):\n'
        '    def __init__(self):\n'
        '        super().__init__("ctrl_c_while_building")\n',
        '        raise ValueError("half-loaded")\n'
        'raise SystemExit(run(Built, "built", startup_errors=(ValueError,)))\n',
        indent=' ' * 8)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'cannot start' not in proc.stdout + proc.stderr


def test_a_ctrl_c_swallowed_during_the_imports_still_stops_the_node(ros_env):
    """trimesh's optional imports catch BaseException: a KeyboardInterrupt raised there never
    reaches the node. It must stop all the same, with 0, instead of serving on (the old code
    served on: a timeout here)."""
    proc = _python_with_a_swallowed_ctrl_c(
        ros_env, 'import advocc_ros.nodes\n',
        'from advocc_ros.nodes.attacker import main\n'
        'raise SystemExit(main())\n', timeout_s=30)
    assert proc.returncode == 0, proc.stdout + proc.stderr


_HALF_BUILT = (
    'from rclpy.node import Node\n'
    'import advocc_ros.nodes\n'
    'class HalfBuilt(Node):\n'
    '    def __init__(self):\n'
    '        super().__init__("half_built")\n'
    '        raise ValueError("bad scene")\n'
    '    def destroy_node(self):\n'
    '        print("destroying", flush=True)\n'
    '        {destroy}\n'
    '        return super().destroy_node()\n'
    'advocc_ros.nodes.SHUTDOWN_LIMIT_S = 3.0\n'
    'raise SystemExit(advocc_ros.nodes.run(HalfBuilt, "half", startup_errors=(ValueError,)))\n')


def test_a_node_whose_constructor_fails_is_destroyed_before_the_exit(ros_env):
    """A constructor that raises after rclpy's Node.__init__ leaves a half-built node: run
    destroys it (one left to the interpreter's teardown hung a CI run after 'cannot start')."""
    proc = subprocess.run([sys.executable, '-c', _HALF_BUILT.format(destroy='pass')],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'cannot start: bad scene' in proc.stderr and 'destroying' in proc.stdout


def test_a_shutdown_that_hangs_ends_the_process_with_where_it_hung(ros_env):
    """Past SHUTDOWN_LIMIT_S after the spin (here 3 s), a stuck shutdown prints the stacks and
    exits 1: a node's process always ends."""
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, '-c', _HALF_BUILT.format(destroy='__import__("time").sleep(600)')],
        env=ros_env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'Timeout' in proc.stderr and 'destroy_node' in proc.stderr  # faulthandler's stacks
    assert time.monotonic() - start < 100
