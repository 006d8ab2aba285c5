"""The demo's benchmark judges planners only on tasks that keep a solution."""

from advocc_ros.cli import build_parser


def test_demo_benchmark_runs_the_solvable_policy_by_default():
    args = build_parser().parse_args(['demo'])
    assert args.bench_policy == 'solvable'
    assert build_parser().parse_args(['demo', '--bench-policy', 'paper']).bench_policy == 'paper'
