"""``python -m fuzz``: generate, run and classify malformed inputs; print and write the counts.

File inputs run in a watched worker pool (:mod:`fuzz.pool`); service requests go to live
``heatmap_server`` and ``planner_shim`` processes on their own ROS domain, at the same time.
Exit code 1 when any input crashed, hung or was wrongly accepted; every such input is written
to ``<out>/cases/`` so it can be replayed.
"""

from __future__ import annotations

import argparse
import collections
import json
import pathlib
import sys
import tempfile
import threading
import time

from fuzz import files
from fuzz.classify import CATEGORIES, FAILING

SHARES = {'scene_yaml': 14, 'mbm_scene': 12, 'mbm_request': 12, 'obstacles': 10, 'heatmap': 18,
          'cloud_ply': 12, 'cloud_pcd': 12, 'srv_attack': 5, 'srv_plan': 5}
"""Relative number of inputs per family (services are slow: seconds per request)."""

_EXAMPLES = 5
"""Details kept per family and non-ok category in the report."""


def plan_counts(total: int, families: list[str]) -> dict[str, int]:
    """Inputs per family: ``total`` split by :data:`SHARES`, at least one each."""
    weight = sum(SHARES[f] for f in families)
    counts = {f: max(1, total * SHARES[f] // weight) for f in families}
    counts[families[0]] += max(0, total - sum(counts.values()))
    return counts


class Tally:
    """Counts per family and category, examples of each non-ok outcome, and timings."""

    def __init__(self, out: pathlib.Path, seed: int, base: dict, workdir: pathlib.Path):
        self.counts = collections.defaultdict(collections.Counter)
        self.examples: dict = collections.defaultdict(lambda: collections.defaultdict(list))
        self.slowest: dict = collections.defaultdict(lambda: (0.0, -1))
        self.lock = threading.Lock()
        self.out, self.seed, self.base, self.workdir = out, seed, base, workdir
        self.done = 0

    def record(self, job, category: str, detail: str, seconds: float) -> None:
        family, index = job
        with self.lock:
            self.counts[family][category] += 1
            self.slowest[family] = max(self.slowest[family], (seconds, index))
            kept = self.examples[family][category]
            if category != 'ok' and len(kept) < _EXAMPLES:
                kept.append({'index': index, 'detail': detail, 'seconds': round(seconds, 3)})
            self.done += 1
        if category in FAILING and family in files.FAMILIES:
            try:
                item = files.generate(family, index, self.seed, self.base, self.workdir)
            except Exception as exc:  # a bug of the generator: the detail already says so
                print(f'{family} {index}: cannot generate ({exc!r})', file=sys.stderr)
                return
            case = self.out / 'cases' / f'{family}_{index}_{category}_{item.name}'
            case.parent.mkdir(parents=True, exist_ok=True)
            case.write_bytes(item.data)

    def table(self) -> str:
        head = f'{"family":<13}' + ''.join(f'{c:>14}' for c in CATEGORIES) + f'{"max s":>8}'
        rows = [head]
        for family in sorted(self.counts):
            c = self.counts[family]
            rows.append(f'{family:<13}' + ''.join(f'{c[k]:>14}' for k in CATEGORIES)
                        + f'{self.slowest[family][0]:>8.2f}')
        total = collections.Counter()
        for c in self.counts.values():
            total.update(c)
        rows.append(f'{"total":<13}' + ''.join(f'{total[k]:>14}' for k in CATEGORIES))
        return '\n'.join(rows)


def _heatmap(path: pathlib.Path) -> None:
    """A small valid heatmap of table_pick: the base every heatmap mutation starts from."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    from advocc_ros.model.scene import load_scene
    scene = load_scene(files.SCENES / 'table_pick.yaml')
    save_heatmap(build_heatmap(scene, HeatmapConfig(samples=300, voxel_m=0.05), seed=4), path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m fuzz', description=__doc__)
    parser.add_argument('--inputs', type=int, default=10_000, help='total inputs (default 10000)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--first', type=int, default=0,
                        help='index of the first input of each family (replay: --families F '
                        '--first N --inputs 1)')
    parser.add_argument('--workers', type=int, default=2, help='parser worker processes')
    parser.add_argument('--timeout-s', type=float, default=20.0,
                        help='per input; past it the input is a hang (default 20)')
    parser.add_argument('--service-timeout-s', type=float, default=60.0,
                        help='per service request (default 60: an attack may spend the 30 s '
                        'budget of its witness search, then its goal probe)')
    parser.add_argument('--families', default=','.join(SHARES),
                        help=f'comma-separated subset of {",".join(SHARES)}')
    parser.add_argument('--out', default='out/fuzz', help='report.json and failing cases here')
    args = parser.parse_args(argv)
    families = [f for f in args.families.split(',') if f]
    unknown = sorted(set(families) - set(SHARES))
    if unknown or not families:
        parser.error(f'unknown families {unknown}; choose from {",".join(SHARES)}')
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    counts = plan_counts(args.inputs, families)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='advocc_fuzz_') as tmp:
        tmp = pathlib.Path(tmp)
        _heatmap(tmp / 'base.npz')
        context = {'seed': args.seed, 'heatmap': str(tmp / 'base.npz'), 'tmp': str(tmp),
                   'first': args.first, 'logs': str(out / 'logs')}
        tally = Tally(out, args.seed, files.bases(context), tmp)
        services = [f for f in families if f.startswith('srv_')]
        thread = None
        if services:
            from fuzz import services as srv
            thread = threading.Thread(target=srv.run_all, daemon=True, args=(
                {f: counts[f] for f in services}, context, args.service_timeout_s,
                tally.record))
            thread.start()
        jobs = [(f, i) for f in families if f in files.FAMILIES
                for i in range(args.first, args.first + counts[f])]
        jobs.sort(key=lambda job: (job[1], job[0]))  # families interleaved: load spreads out
        files_run = threading.Thread(target=_progress, args=(tally, sum(counts.values())),
                                     daemon=True)
        files_run.start()
        from fuzz.pool import run_pool
        run_pool(jobs, 'fuzz.files', context, args.workers, args.timeout_s, tally.record)
        if thread is not None:
            thread.join()
    elapsed = time.monotonic() - t0
    return _report(tally, out, args, counts, elapsed)


def _progress(tally: Tally, total: int) -> None:
    while tally.done < total:
        time.sleep(30)
        print(f'  {tally.done}/{total} inputs', file=sys.stderr, flush=True)


def _report(tally: Tally, out: pathlib.Path, args, counts: dict, elapsed: float) -> int:
    from advocc_ros.fileio import atomic_open
    failing = {f: {k: c[k] for k in FAILING if c[k]} for f, c in tally.counts.items()}
    failing = {f: v for f, v in failing.items() if v}
    missing = {f: n - sum(tally.counts[f].values()) for f, n in counts.items()
               if sum(tally.counts[f].values()) < n}
    if missing:  # e.g. a node that never came up: fewer inputs ran than planned
        failing['not run'] = missing
    report = {
        'inputs': sum(sum(c.values()) for c in tally.counts.values()), 'planned': counts,
        'seed': args.seed, 'workers': args.workers, 'timeout_s': args.timeout_s,
        'service_timeout_s': args.service_timeout_s,
        'elapsed_s': round(elapsed, 1),
        'counts': {f: {k: c[k] for k in CATEGORIES} for f, c in sorted(tally.counts.items())},
        'slowest': {f: {'seconds': round(s, 3), 'index': i}
                    for f, (s, i) in sorted(tally.slowest.items())},
        'examples': {f: dict(e) for f, e in sorted(tally.examples.items())},
        'failing': failing,
    }
    with atomic_open(out / 'report.json', 'w') as handle:
        json.dump(report, handle, indent=1)
    print(tally.table())
    print(f'{report["inputs"]} inputs in {elapsed:.0f} s; report: {out / "report.json"}')
    if failing:
        print(f'FAILED: {json.dumps(failing)}; inputs in {out / "cases"}')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
