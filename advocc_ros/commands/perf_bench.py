"""``advocc perf bench``: benchmark throughput, trials/s with 1 and 2 planner shims.

Runs a bench profile (default ``quick``) once per shim count, each in a fresh run folder, and
reports the orchestrator's ``trials_per_s``: trials over the wall time of the trial loops only
(node start-up, heatmap builds and attacks excluded), so the figure is the planning throughput
the shims deliver. Wired into ``advocc perf`` by ``commands/perf.py`` calling
:func:`register_bench`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile

from advocc_ros.cli import UserError
from advocc_ros.evaluation.perf import machine
from advocc_ros.paths import config_dir


def register_bench(sub: argparse._SubParsersAction) -> None:
    """Add ``bench`` to the ``advocc perf`` subcommands."""
    p = sub.add_parser('bench', help='bench throughput (trials/s) with 1 and 2 planner shims')
    p.add_argument('--profile', default='quick', help='bench profile (default %(default)s)')
    p.add_argument('--shims', default='1,2', help='comma-separated shim counts')
    p.add_argument('--trials', type=int, help='trials per cell (default: the profile\'s)')
    p.add_argument('--out', help='folder for the runs (default: a new temporary folder)')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=_perf_bench)


def _perf_bench(args) -> int:
    from advocc_ros.bench import BenchConfig, load_profile
    from advocc_ros.orchestrator.run import Orchestrator

    try:
        counts = [int(n) for n in args.shims.split(',') if n.strip()]
    except ValueError:
        raise UserError(f'--shims: expected integers like 1,2, got {args.shims!r}') from None
    if not counts or min(counts) < 1:
        raise UserError('--shims: give at least one shim count >= 1')
    base = load_profile(config_dir() / 'bench.yaml', args.profile).to_data()
    if args.trials is not None:
        base['trials'] = args.trials
    out = pathlib.Path(args.out or tempfile.mkdtemp(prefix='advocc_perf_bench_'))
    runs = {}
    for n in counts:
        run_dir = out / f'shims{n}'
        if run_dir.exists() and any(run_dir.iterdir()):
            raise UserError(f'{run_dir} is not empty: a resumed run would skip its trials')
        cfg = BenchConfig.from_data(dict(base, shims=n), f'profile {args.profile}, {n} shims')
        summary = Orchestrator(cfg, run_dir).run()
        runs[str(n)] = {key: summary.get(key) for key in
                        ('status', 'reason', 'internal_errors', 'trials_run', 'trial_phase_s',
                         'trials_per_s', 'wall_s')}
    report = {'benchmark': 'bench throughput', 'profile': args.profile,
              'time_budget_s': base.get('time_budget_s'), 'runs': runs, 'out': str(out),
              'machine': machine()}
    rates = [runs[str(n)]['trials_per_s'] for n in counts]
    if len(counts) > 1 and all(rates):
        report['scaling'] = {f'{n}/{counts[0]}': round(r / rates[0], 2)
                             for n, r in zip(counts[1:], rates[1:])}
    print(json.dumps(report, indent=2) if args.json else
          '\n'.join(f'{n} shim(s): {runs[str(n)]["trials_run"]} trials, '
                    f'{runs[str(n)]["trials_per_s"]} trials/s' for n in counts)
          + (f'\nscaling: {report["scaling"]}' if 'scaling' in report else ''))
    return 0
