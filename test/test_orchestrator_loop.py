"""The orchestrator's run loop without a ROS graph: a fake shim pool answers plan requests.

The loop's bookkeeping is under test (records, resume, a dead or hung shim restarted once with
its trial requeued, internal errors retried, capped, recorded apart and failing the run, the
summary of an incomplete run); test_orchestrator.py runs the same loop through real node
processes.
"""

import json
import socket
import time

import numpy as np
import pytest

from advocc_ros.bench import BenchConfig, BenchError, RecordStore
from advocc_ros.evaluation import provenance
from advocc_ros.orchestrator.run import Orchestrator
from advocc_ros.orchestrator.shims import CallFailed, PlanAnswer, Shim, ShimState

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
        try:
            out = self.answer(self, shim, job)
        except CallFailed:  # like RosShimPool: a failed call is forgotten
            del self.inflight[shim.name]
            raise
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
    made = provenance.code()
    for r in records:
        # each names its making: this checkout's commit, the host, a load
        assert (r['commit'], r['dirty'], r['host']) == (made['commit'], made['dirty'],
                                                        socket.gethostname())
        assert r['cpu'] and r['load_1min'] >= 0
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


def _fails_on(seed, fail):
    """An answer script: ``fail(job)`` (returns an answer or raises) for trials of ``seed``,
    success for the others; and the seeds of every plan call, in order."""
    calls = []

    def answer(pool, shim, job):
        calls.append(job.seed)
        return fail(job) if job.seed == seed else _success(job)
    return answer, calls


def _csv_rows(path):
    import csv
    return list(csv.DictReader(path.open()))


def test_internal_errors_are_retried_then_recorded_apart_and_fail_the_run(tmp_path):
    """A shim that crashes on one trial of three: the trial is planned 3 times, recorded as an
    internal error, left out of PSR (2/2 = 100 %), counted in the tables, and with 1 of 3
    (> 5 %) internal errors the run fails and the summary says why."""
    run = tmp_path / 'run'
    _cache_attack(run)
    answer, calls = _fails_on(0, lambda job: PlanAnswer('CRASH', -29, 'worker died', 0.0, 0))
    summary, _ = _run(run, answer, _cfg(planners=('rrtconnect',), baseline=False))
    assert calls.count(0) == 3  # first try + 2 retries
    crashed = [r for r in _records(run) if r['seed'] == 0]
    assert [r['status'] for r in crashed] == ['CRASH']
    assert summary['status'] == 'failed' and summary['internal_errors'] == 1
    assert 'table_pick/rrtconnect/random/1 (1 of 3)' in summary['reason']
    (row,) = _csv_rows(run / 'table1.csv')
    assert (row['trials'], row['internal_errors'], row['successes']) == ('3', '1', '2')
    assert float(row['psr_percent']) == 100.0
    (row,) = _csv_rows(run / 'failures.csv')
    assert row['internal_errors'] == '1' and row['planning_failed'] == '0'
    assert '100.00!' in (run / 'table1.md').read_text()


def test_internal_errors_up_to_five_percent_of_a_cell_pass(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)

    def answer(pool, shim, job):
        if job.seed == 3:
            return PlanAnswer('INTERNAL_ERROR', -105, 'worker: RuntimeError()', 0.0, 0)
        return _success(job) if job.seed % 2 else _failure(job)

    summary, _ = _run(run, answer, _cfg(planners=('rrtconnect',), baseline=False, trials=20))
    assert summary['status'] == 'complete' and summary['reason'] is None
    assert summary['internal_errors'] == 1
    (row,) = _csv_rows(run / 'table1.csv')
    assert (row['trials'], row['internal_errors'], row['successes']) == ('20', '1', '9')
    assert float(row['psr_percent']) == pytest.approx(100 * 9 / 19)


def test_a_success_whose_path_collides_is_an_internal_error(tmp_path):
    """The shim's "successful" path passes through the attack's box: not CMR 0, an error."""
    run = tmp_path / 'run'
    _cache_attack(run)
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.model.scene import load_scene
    from advocc_ros.paths import scene_path

    scene = load_scene(scene_path('table_pick'))
    world = CollisionWorld(load_robot(scene.robot), scene.shapes)
    rng = np.random.default_rng(0)
    robot = world.robot
    q_bad = next(q for q in rng.uniform(robot.lower, robot.upper, (500, robot.nq))
                 if world.collisions_batch(q[None], 1)[0])

    def answer(pool, shim, job):
        if job.seed == 1:
            path = np.stack([job.q_start, q_bad])
            return PlanAnswer('SUCCESS', 1, 'solved', 0.1, 2, path)
        return _success(job)

    summary, _ = _run(run, answer, _cfg(planners=('rrtconnect',), methods=('random',),
                                        budgets=(1,), trials=3))
    bad = [r for r in _records(run) if r['seed'] == 1]
    assert {r['status'] for r in bad} == {'INTERNAL_ERROR'}
    assert all(not r['success'] and r['min_clearance_rad'] is None for r in bad)
    assert all('waypoint 1 is in collision' in r['message'] for r in bad)
    assert summary['internal_errors'] == len(bad) == 2 and summary['status'] == 'failed'


def test_a_cell_of_internal_errors_only_has_no_psr_and_the_report_still_renders(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)

    def answer(pool, shim, job):
        if job.planner_id == 'bkpiece1':
            return PlanAnswer('INTERNAL_ERROR', -105, 'worker: RuntimeError()', 0.0, 0)
        return _success(job)

    summary, _ = _run(run, answer)
    assert summary['status'] == 'failed' and summary['internal_errors'] == 2 * TRIALS
    assert 'bkpiece1/none/0 (3 of 3)' in summary['reason']
    rows = {(r['planner'], r['method']): r for r in _csv_rows(run / 'table1.csv')}
    assert rows[('bkpiece1', 'random')]['psr_percent'] == 'N/A'
    assert float(rows[('rrtconnect', 'random')]['psr_percent']) == 100.0
    assert '| N/A! |' in (run / 'table1.md').read_text()
    assert (run / 'figures' / 'psr_vs_budget_table_pick.png').stat().st_size > 0


def test_a_hung_shim_is_restarted_at_its_deadline_and_its_trial_planned_again(tmp_path):
    run = tmp_path / 'run'
    _cache_attack(run)
    hung = []

    def answer(pool, shim, job):
        if shim.name == '/fake_0' and (not hung or hung[0] is job):
            hung[:1] = [job]
            return None  # never answers
        return _success(job)

    t0 = time.monotonic()
    summary, (pool,) = _run(run, answer, _cfg(time_budget_s=0.2, plan_timeout_margin_s=0.5))
    assert time.monotonic() - t0 >= 0.7  # not before budget + margin
    assert summary['status'] == 'complete' and summary['restarts'] == {'fake_0': 1}
    assert pool.restarted == ['/fake_0']
    records = _records(run)
    assert len({r['key'] for r in records}) == len(records) == summary['planned']
    assert all(r['status'] == 'SUCCESS' for r in records)


def test_failing_plan_calls_are_capped_and_recorded_as_internal_errors(tmp_path):
    """A plan call that always fails on one trial must not loop forever."""
    def no_response(job):
        raise CallFailed('service call returned no response')

    run = tmp_path / 'run'
    _cache_attack(run)
    answer, calls = _fails_on(2, no_response)
    summary, _ = _run(run, answer, _cfg(planners=('rrtconnect',), baseline=False))
    assert calls.count(2) == 3
    (bad,) = [r for r in _records(run) if r['seed'] == 2]
    assert bad['status'] == 'INTERNAL_ERROR' and 'plan call failed' in bad['message']
    assert summary['internal_errors'] == 1 and summary['status'] == 'failed'


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
