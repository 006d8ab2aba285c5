"""``advocc perf load`` scaled down (2 clients x 20 attacks, 2 x 2 plans): every request
succeeds (a plan that times out or fails is not served), every latency measured, node memory
sampled. The full run is a benchmark, not this test."""

import pytest

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs


def test_load_scaled_down(ros_env, monkeypatch):
    from advocc_ros.commands.perf_load import run_load

    monkeypatch.setenv('ROS_DOMAIN_ID', ros_env['ROS_DOMAIN_ID'])
    report = run_load(samples=300, clients=2, requests=20, plan_clients=2, plan_requests=2,
                      plan_budget=2.0)
    attack, plan = report['attack'], report['plan']
    assert attack['requests'] == 40 and attack['failed'] == 0, attack
    assert plan['requests'] == 4 and plan['failed'] == 0, plan
    assert plan['codes'] == {'1': 4}, plan  # every plan solved: no timeout passes as served
    assert attack['codes'] == {'1': 40}, attack
    for r in (attack, plan):
        assert 0 < r['latency_ms']['p50'] <= r['latency_ms']['p99']
        assert r['throughput_per_s'] > 0 and r['rss_mb']['samples'] > 0
        assert r['rss_mb']['before'] > 50  # a real node was measured, not this process
    # No growth beyond noise over 40 attacks (a leak of one heatmap copy would be +9 MB).
    assert attack['rss_mb']['after'] - attack['rss_mb']['before'] < 8, attack['rss_mb']
