"""The transfer table of docs/results/transfer/README.md from two bench runs' CSV tables.

Usage: python make_table.py SOLVABLE_RUN PAPER_RUN > table.md (run folders of ``advocc bench``:
their ``hardness.csv`` and ``failures.csv``). Per scene and planner: PSR at M = 0 / 5 / 10 under
``solvable`` and at M = 5 under ``paper``, the PT ratio (attacked / unattacked median time to
first solution, failures at the budget) at solvable M = 10, and that cell's failure modes.
"""

import csv
import pathlib
import sys

PLANNERS = ('rrtconnect', 'prmstar', 'bkpiece1', 'mplib')
LABELS = {'rrtconnect': 'RRTConnect', 'prmstar': 'PRM*', 'bkpiece1': 'BKPIECE1',
          'mplib': 'MPlib'}
MODES = ('goal_not_sampled', 'timed_out', 'planning_failed', 'invalid_path',
         'goal_invalid_for_victim', 'model_mismatch', 'internal_errors')


def _rows(run: pathlib.Path, name: str) -> dict:
    path = run / name
    if not path.is_file():
        return {}
    with path.open() as f:
        return {(r['scene'], r['planner'], int(r['budget'])): r for r in csv.DictReader(f)}


def main(solvable: str, paper: str) -> None:
    hard, fail = _rows(pathlib.Path(solvable), 'hardness.csv'), _rows(pathlib.Path(solvable),
                                                                      'failures.csv')
    paper_hard = _rows(pathlib.Path(paper), 'hardness.csv')
    scenes = list(dict.fromkeys(scene for scene, _, _ in hard))
    print('| Scene | Planner | PSR M=0 | PSR M=5 | PSR M=10 | PT ratio M=10 | '
          'failures at M=10 | PSR paper M=5 |')
    print('|---|---|---|---|---|---|---|---|')
    for scene in scenes:
        for planner in PLANNERS:
            if (scene, planner, 0) not in hard:
                continue
            psr = [hard.get((scene, planner, m), {}).get('psr_percent', '--') for m in (0, 5, 10)]
            ratio = hard.get((scene, planner, 10), {}).get('pt_ratio', '')
            ratio = f'x{float(ratio):.1f}' if ratio else '--'
            modes = fail.get((scene, planner, 10), {})
            text = ', '.join(f'{m.replace("_", " ")} {modes[m]}' for m in MODES
                             if modes.get(m) not in (None, '', '0')) or '--'
            ref = paper_hard.get((scene, planner, 5), {}).get('psr_percent', '--')
            print(f'| {scene} | {LABELS[planner]} | {psr[0]} | {psr[1]} | {psr[2]} | {ratio} | '
                  f'{text} | {ref} |')


if __name__ == '__main__':
    main(*sys.argv[1:3])
