"""How two pytest-xdist workers share the CPUs (``conftest.CpuTurns``): a timing test waits for
the running tests, no new test starts while it waits, and a run of timing tests keeps its
exclusive turn."""

import threading

from conftest import CpuTurns


def _take(turns: CpuTurns, alone: bool) -> threading.Event:
    """Take ``turns`` in a thread (another worker); the event is set once it is held."""
    held = threading.Event()

    def take():
        turns.take(alone)
        held.set()

    threading.Thread(target=take, daemon=True).start()
    return held


def test_a_timing_test_waits_for_the_running_test_and_blocks_new_ones(tmp_path):
    running, timing, new = (CpuTurns(tmp_path) for _ in range(3))
    running.take(alone=False)
    timing_held = _take(timing, alone=True)
    assert not timing_held.wait(0.5)  # the running test holds the CPUs
    new_held = _take(new, alone=False)
    assert not new_held.wait(0.5)  # no new test passes a waiting timing test
    running.give_back()
    assert timing_held.wait(10) and not new_held.wait(0.5)
    timing.give_back()
    assert new_held.wait(10) and new.alone is False


def test_a_run_of_timing_tests_keeps_its_exclusive_turn(tmp_path):
    timing, other = CpuTurns(tmp_path), CpuTurns(tmp_path)
    timing.take(alone=True)
    other_held = _take(other, alone=False)
    assert not other_held.wait(0.5)
    kept = _take(timing, alone=True)  # the next timing test keeps the turn
    assert kept.wait(10) and timing.alone is True and not other_held.wait(0.5)
    timing.give_back()
    assert other_held.wait(10) and timing.alone is None
