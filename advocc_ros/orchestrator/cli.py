"""The ``orchestrator`` program and ``advocc bench``: the paper's benchmark through real nodes.

A profile of ``config/bench.yaml`` (``paper`` or ``quick``) sets the protocol; every setting can
be overridden here. Re-running the same command on the same ``--out`` folder resumes it.
"""

from __future__ import annotations

import argparse
import json
import logging
import pathlib
import sys

import yaml

from advocc_ros.paths import config_dir

_DESCRIPTION = "orchestrator: runs the paper's benchmark through real nodes (docs/design.md)."


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(',') if v.strip()]


def _ints(text: str) -> list[int]:
    try:
        return [int(v) for v in _names(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected integers like 1,3,5, got {text!r}') from None


def _pairs(text: str) -> dict[str, int]:
    out = {}
    for item in _names(text):
        key, sep, value = item.partition('=')
        if not sep:
            raise argparse.ArgumentTypeError(f'expected METHOD=COUNT, got {item!r}')
        try:
            out[key] = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{item!r}: COUNT must be an integer') from None
    return out


def add_bench_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--profile', default='quick',
                        help='profile of the bench config: paper | quick (default %(default)s)')
    parser.add_argument('--config', default=None,
                        help='bench YAML with profiles (default: config/bench.yaml)')
    parser.add_argument('--out', required=True, help='run folder (re-run to resume)')
    g = parser.add_argument_group('protocol overrides (default: the profile\'s)')
    g.add_argument('--scenes', type=_names, help='comma list: names in config/scenes or files')
    g.add_argument('--planners', type=_names, help='comma list: rrtconnect,prmstar,bkpiece1')
    g.add_argument('--methods', type=_names, help='comma list: ours,random,pfa,pfa++')
    g.add_argument('--budgets', type=_ints, help='Table I budgets, e.g. 1,3,5')
    g.add_argument('--sweep-budgets', type=_ints, help='extra budgets for Table II')
    g.add_argument('--trials', type=int, help='trials per cell')
    g.add_argument('--sweep-trials', type=int, help='trials per sweep-only budget')
    g.add_argument('--time-budget', type=float, dest='time_budget_s',
                   help='planning budget per trial [s]')
    g.add_argument('--variants', type=_pairs, help='attacks per cell, e.g. random=10')
    g.add_argument('--no-baseline', dest='baseline', action='store_false', default=None,
                   help='skip the unattacked scenes')
    g.add_argument('--seed', type=int)
    g.add_argument('--box-size', type=float, dest='box_size_m', help='box edge [m]')
    g.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                   help='any other bench setting (YAML value), e.g. --set attack_timeout_s=600')
    n = parser.add_argument_group('nodes')
    n.add_argument('--shims', type=int, help='local planner_shim processes')
    n.add_argument('--external-shims', action='store_true', default=None,
                   help='also use planner shims found on this ROS domain (other hosts)')
    n.add_argument('--domain', type=int, help='ROS_DOMAIN_ID for the orchestrator and nodes')
    n.add_argument('--heatmap', action='append', default=[], metavar='[SCENE=]FILE',
                   help='heatmap file (for SCENE, or all scenes); several files for one scene '
                        'are shards, merged into the run folder')
    n.add_argument('--heatmap-samples', type=int, help='samples of heatmaps built here')
    n.add_argument('--report-only', action='store_true',
                   help='only rewrite the tables, cells.csv and figures from the run folder\'s '
                   'records, under the settings it was measured with (its config.json)')
    n.add_argument('--json', action='store_true', help='print the run summary as JSON')


_DIRECT = ('scenes', 'planners', 'methods', 'budgets', 'sweep_budgets', 'trials',
           'sweep_trials', 'time_budget_s', 'variants', 'baseline', 'seed', 'box_size_m',
           'shims', 'external_shims', 'heatmap_samples')


def bench_config(args: argparse.Namespace):
    """The profile with the command line's overrides applied."""
    from advocc_ros.bench import BenchConfig, BenchError, load_profile

    path = pathlib.Path(args.config) if args.config else config_dir() / 'bench.yaml'
    base = load_profile(path, args.profile).to_data()
    for key in _DIRECT:
        value = getattr(args, key, None)
        if value is not None:
            base[key] = value
    for item in args.set:
        key, sep, text = item.partition('=')
        if not sep:
            raise BenchError(f'--set {item!r}: expected KEY=VALUE')
        base[key.strip()] = yaml.safe_load(text)
    return BenchConfig.from_data(base, f'{path}:{args.profile} + command line')


def heatmap_args(items: list[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for item in items:
        scene, sep, path = item.rpartition('=')
        out.setdefault(scene if sep else '*', []).append(str(pathlib.Path(path).resolve()))
    return out


def _measured_config(run_dir: pathlib.Path, cfg):
    """The settings a run folder's trials were measured with (its ``config.json``), else
    ``cfg``: a report of an older run needs no command line to match it."""
    from advocc_ros.bench import BenchConfig, BenchError

    path = run_dir / 'config.json'
    if not path.exists():
        return cfg
    try:
        return BenchConfig.from_data(json.loads(path.read_text())['config'], str(path))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchError(f'{path}: unreadable ({exc})') from None


def run(args: argparse.Namespace) -> int:
    from advocc_ros.bench.report import write_report
    from advocc_ros.orchestrator.run import Orchestrator

    cfg = bench_config(args)
    out = pathlib.Path(args.out)
    if args.report_only:
        files = write_report(out, _measured_config(out, cfg))
        for name in files:
            print(out / name)
        return 0
    summary = Orchestrator(cfg, out, heatmap_args(args.heatmap), args.domain).run()
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f'{summary["done"]}/{summary["planned"]} trials in {out} '
              f'({summary["status"]}, {summary["wall_s"]:.0f} s)')
        for note in summary['notes']:
            print(f'note: {note}')
        sys.stdout.write((out / 'table1.md').read_text())
    if summary['internal_errors']:
        print(f'warning: {summary["internal_errors"]} trials were internal errors (left out of '
              f'PSR; failures.md counts them per cell)', file=sys.stderr)
    if summary['reason']:
        print(f'orchestrator: run failed: {summary["reason"]}', file=sys.stderr)
    return 0 if summary['missing'] == 0 and summary['status'] != 'failed' else 1


def main(argv: list[str] | None = None) -> int:
    """The ``orchestrator`` executable: same options as ``advocc bench``."""
    from advocc_ros.bench import BenchError

    parser = argparse.ArgumentParser(prog='orchestrator', description=_DESCRIPTION)
    parser.add_argument('-v', '--verbose', action='store_true', help='debug logging')
    add_bench_args(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format='%(levelname)s %(name)s: %(message)s')
    try:
        return run(args)
    except (BenchError, ValueError, OSError) as exc:
        print(f'orchestrator: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('orchestrator: interrupted; finished trials are kept (re-run to resume)',
              file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
