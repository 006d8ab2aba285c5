"""The orchestrator's run loop without a ROS graph: a fake shim pool answers plan requests.

The loop's bookkeeping is under test (records, resume, a dead shim restarted once with its trial
requeued, crash retries, the summary of an incomplete run); test_orchestrator.py runs the same
loop through real node processes.
"""

import json
import time

import numpy as np
import pytest

from advocc_ros.bench import BenchConfig, BenchError, RecordStore
from advocc_ros.orchestrator.run import Orchestrator
from advocc_ros.orchestrator.shims import PlanAnswer, Shim, ShimState

PLANNERS = ('rrtconnect', 'bkpiece1')
TRIALS = 3


def _cfg(**kw):
    base = dict(scenes=('table_pick',), planners=PLANNERS, methods=('random',), budgets=(1,),
                trials=TRIALS, time_budget_s=1.0, shims=2, heatmap_workers=1,
                plan_timeout_margin_s=5.0, max_restarts=2)
    base.update(kw)
    return BenchConfig(**base)


def _cache_attack(run_dir):
    """A cached random_b1_v0 attack, so no heatmap server is needed."""
    from advocc_ros.attack import save_obstacles
    from advocc_ros.attack.obstacles import obstacles_file_data
    from advocc_ros.model.scene import make_box

    boxes = (make_box('random_b1_v0_0', (0.6, 0.6, 1.5), (0.05, 0.05, 0.05)),)
    save_obstacles(run_dir / 'attacks' / 'table_pick' / 'random_b1_v0.yaml',
                   obstacles_file_data(boxes, 'random', 1, 'success'))


def _success(job):
    path = np.stack([job.q_start, job.q_start + 0.01])
    return PlanAnswer('SUCCESS', 1, 'solved', 0.1, len(path), path)


def _failure(job):
    return PlanAnswer('TIMED_OUT', -6, 'no solution in time', 1.0, 0)


class FakePool:
    """In-process ShimPool: ``answer(pool, shim, job)`` scripts each plan request's answer
    (None: no answer yet, e.g. the shim just died)."""

    def __init__(self, orch, answer):
        self.answer = answer
        self.shims = [Shim(f'/fake_{i}', since=time.monotonic()) for i in range(orch.cfg.shims)]
        self.inflight = {}
        self.exits = {}
        self.plans = []
        self.injected = []
        self.restarted = []
        self.closed = False

    def inject(self, objects):
        self.injected.append(tuple(o.id for o in objects))
        for shim in self.shims:
            if shim.state in (ShimState.IDLE, ShimState.SYNC):
                shim.state = ShimState.SYNC

    def sync(self, shim, now):
        shim.state = ShimState.SYNC if shim.state == ShimState.STARTING else ShimState.IDLE
        return None

    def plan(self, shim, job):
        assert shim.state == ShimState.IDLE and shim.name not in self.inflight
        self.inflight[shim.name] = job
        self.plans.append((shim.name, job))

    def poll(self, shim):
        job = self.inflight[shim.name]
        out = self.answer(self, shim, job)
        if out is not None:
            del self.inflight[shim.name]
        return out

    def exit_code(self, shim):
        return self.exits.pop(shim.name, None)

    def restart(self, shim):
        self.inflight.pop(shim.name, None)
        self.restarted.append(shim.name)
        shim.state = ShimState.STARTING

    def drop(self, shim):
        self.inflight.pop(shim.name, None)
        shim.state = ShimState.DEAD

    def output(self, shim):
        return ''

    def discover(self, wait=False):
        pass

    def spin(self, timeout_s):
        pass

    def close(self):
        self.closed = True


def _run(run_dir, answer, cfg=None):
    pools = []

    def factory(orch):
        pools.append(FakePool(orch, answer))
        return pools[-1]

    summary = Orchestrator(cfg or _cfg(), run_dir, pool_factory=factory).run()
    assert summary == json.loads((run_dir / 'summary.json').read_text())
    return summary, pools


def _records(run_dir):
    lines = (run_dir / 'records.jsonl').read_text().splitlines()
    return [json.loads(line) for line in lines]


def test_loop_records_every_trial(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)
    summary, (pool,) = _run(run, lambda p, s, job: (_success if job.seed % 2 == 0
                                                    else _failure)(job))
    planned = len(PLANNERS) * TRIALS * 2  # baseline + random
    assert summary['status'] == 'complete' and summary['done'] == planned
    assert summary['missing'] == 0 and summary['restarts'] == {}
    records = _records(run)
    assert len({r['key'] for r in records}) == len(records) == planned
    assert pool.injected == [(), ('random_b1_v0_0',)] and pool.closed
    assert {r['shim'] for r in records} == {'/fake_0', '/fake_1'}
    for r in records:
        assert r['success'] == (r['seed'] % 2 == 0)
        assert r['attack'] == (None if r['method'] == 'none' else 'random_b1_v0')
        if r['success']:
            assert r['status'] == 'SUCCESS' and r['waypoints'] == 2
            assert r['jds_rad'] > 0 and r['min_manipulability'] > 0
        else:
            assert r['status'] == 'TIMED_OUT' and r['jds_rad'] is None
    assert (run / 'table1.md').exists()
    # Re-running the finished run plans nothing.
    summary, pools = _run(run, lambda p, s, job: pytest.fail('planned a finished trial'))
    assert summary['status'] == 'complete' and pools == []


def test_dead_shim_is_restarted_once_and_its_trial_requeued(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)
    killed = []

    def answer(pool, shim, job):
        if shim.name == '/fake_0' and not killed:  # dies with a request in flight
            killed.append(job)
            pool.exits[shim.name] = -9
            return None
        return _success(job)

    summary, (pool,) = _run(run, answer)
    assert summary['status'] == 'complete' and summary['missing'] == 0
    assert summary['restarts'] == {'fake_0': 1}
    assert pool.restarted == ['/fake_0']
    records = _records(run)
    assert len({r['key'] for r in records}) == len(records) == len(PLANNERS) * TRIALS * 2
    # The killed trial was planned again (on some shim) and recorded once.
    assert len(pool.plans) == len(records) + 1


def test_a_shim_dying_too_often_fails_the_run_and_the_summary_says_so(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)

    def answer(pool, shim, job):
        if shim.name == '/fake_0':
            pool.exits[shim.name] = -9
            return None
        return _success(job)

    with pytest.raises(BenchError, match='fake_0 failed 3 times'):
        _run(run, answer, _cfg(shims=1))
    summary = json.loads((run / 'summary.json').read_text())
    assert summary['status'] == 'failed' and summary['restarts'] == {'fake_0': 3}
    assert summary['missing'] == summary['planned'] - summary['done'] > 0


def test_crashes_are_retried_then_recorded(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)
    calls = []

    def answer(pool, shim, job):
        calls.append(job.seed)
        if job.seed == 0:
            return PlanAnswer('CRASH', -29, 'worker died', 0.0, 0)
        return _success(job)

    summary, _ = _run(run, answer, _cfg(planners=('rrtconnect',), baseline=False))
    assert summary['status'] == 'complete'
    assert calls.count(0) == 3  # first try + 2 retries
    crashed = [r for r in _records(run) if r['seed'] == 0]
    assert [r['status'] for r in crashed] == ['CRASH']


def test_interrupted_run_reports_and_resumes(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)
    answered = []

    def stop_after_four(pool, shim, job):
        if len(answered) == 4:
            raise KeyboardInterrupt
        answered.append(job)
        return _success(job)

    with pytest.raises(KeyboardInterrupt):
        _run(run, stop_after_four)
    summary = json.loads((run / 'summary.json').read_text())
    assert summary['status'] == 'interrupted'
    first = _records(run)
    assert summary['done'] == len(first) >= 3 and summary['missing'] > 0

    summary, (pool,) = _run(run, lambda p, s, job: _success(job))
    assert summary['status'] == 'complete' and summary['missing'] == 0
    records = _records(run)
    assert records[:len(first)] == first  # finished trials kept, not planned again
    assert len(pool.plans) == summary['planned'] - len(first)
    assert len(RecordStore(run / 'records.jsonl')) == summary['planned']


def test_a_signal_while_a_record_is_written_keeps_it_counted(tmp_path, monkeypatch):
    """SIGINT between the record's fsync and the store's update: the summary counts it."""
    import os
    import signal

    run = tmp_path / 'run'
    _cache_attack(run)
    fsync = os.fsync
    synced = []

    def fsync_then_sigint(fd):
        fsync(fd)
        if os.readlink(f'/proc/self/fd/{fd}').endswith('records.jsonl'):
            synced.append(fd)
            if len(synced) == 3:
                os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(os, 'fsync', fsync_then_sigint)
    with pytest.raises(KeyboardInterrupt):
        _run(run, lambda p, s, job: _success(job))
    summary = json.loads((run / 'summary.json').read_text())
    assert summary['status'] == 'interrupted'
    assert summary['done'] == len(_records(run)) == 3
