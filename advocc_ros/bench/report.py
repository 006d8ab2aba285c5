"""The run folder's report: tables, figures and summary from its records (no ROS, no nodes)."""

from __future__ import annotations

import json
import logging
import pathlib
from typing import Any

from advocc_ros.attack.obstacles import obstacles_meta
from advocc_ros.bench.protocol import BASELINE, BenchConfig, variation_scenes
from advocc_ros.bench.records import RecordStore
from advocc_ros.bench.tables import (baseline_table, cell_rows, failure_table, hardness_table,
                                     table1, table2, table4)
from advocc_ros.evaluation.hardness import solution_times
from advocc_ros.fileio import atomic_write_text
from advocc_ros.model.scene import read_yaml

log = logging.getLogger(__name__)


def _attack_metas(run_dir: pathlib.Path) -> list[dict]:
    metas = []
    for path in sorted((run_dir / 'attacks').glob('*/*.yaml')):
        try:
            data = read_yaml(path)
        except Exception as exc:  # noqa: BLE001 - one bad file must not hide the tables
            log.warning('%s: %s', path, exc)
            continue
        if isinstance(data, dict):
            metas.append(obstacles_meta(data) | {'path': path})
    return metas


def write_report(run_dir: str | pathlib.Path, cfg: BenchConfig, summary: dict | None = None
                 ) -> dict[str, pathlib.Path]:
    """Tables I, II, IV (+ baseline) as Markdown and CSV, figures, summary; all atomic."""
    import advocc_ros.bench.figures as figures
    from advocc_ros.evaluation.figures import plot_heatmap_slices
    from advocc_ros.attack import load_obstacles
    from advocc_ros.heatmap import HeatmapError, load_heatmap
    from advocc_ros.paths import scene_path
    from advocc_ros.model.scene import SceneError, load_scene

    run_dir = pathlib.Path(run_dir)
    store = RecordStore(run_dir / 'records.jsonl')
    rows = cell_rows(store.records.values(), cfg)
    out: dict[str, pathlib.Path] = {}

    def put(name: str, text: str) -> None:
        atomic_write_text(run_dir / name, text)
        out[name] = run_dir / name

    md1, csv1 = table1(rows, cfg)
    md2, csv2 = table2(rows, cfg, variation_scenes(cfg, run_dir))
    heatmap_meta: dict[str, dict] = {}
    heatmaps: dict[str, Any] = {}
    try:
        sources = json.loads((run_dir / 'config.json').read_text()).get('heatmaps', {})
    except (OSError, ValueError):
        sources = {}
    for scene in cfg.scenes:
        built = run_dir / 'heatmaps' / f'{pathlib.Path(scene_path(scene)).stem}.npz'
        files = sources.get(scene) or ([str(built)] if built.exists() else None)
        if not files:
            continue
        try:
            heatmaps[scene] = load_heatmap(files[0])
            heatmap_meta[scene] = heatmaps[scene].meta
        except HeatmapError as exc:
            log.warning('heatmap of %s: %s', scene, exc)
    metas = _attack_metas(run_dir)
    md4, csv4 = table4(metas, heatmap_meta)
    notes = (summary or {}).get('notes', [])
    head = (f'Time budget {cfg.time_budget_s:g} s, {cfg.trials} trials per cell planned '
            f'(`*`: fewer finished). PSR in %, SMR and CMR x10^-2, JDS in rad, PT in s.\n')
    base = baseline_table(rows, cfg)
    base = f'\n## Unattacked baseline (budget 0)\n\n{base}' if base.count('\n') > 2 else ''
    put('table1.md', f'# Table I: attack performance\n\n{head}\n{md1}{base}'
        + ''.join(f'\n- {n}' for n in notes) + ('\n' if notes else ''))
    put('table1.csv', csv1)
    put('table2.md', '# Table II: minimum budget to reach PSR <= threshold\n\n'
        'Smallest measured budget (0 = unattacked) whose PSR is at or below the threshold; '
        '"> M" when the largest measured budget M does not reach it. With variations, the mean '
        'over the scene and its variations ("Tasks") that reach it; "(k/n)": only k of n do.'
        '\n\n' + md2)
    put('table2.csv', csv2)
    put('table4.md', '# Table IV: offline and online time per method (s)\n\n'
        'Offline: heatmap build (Ours and Task search its H > 0 voxels). Online: core compute '
        'time of one attack, mean over the attacks generated in this run.\n\n' + md4)
    put('table4.csv', csv4)
    stems = {scene: pathlib.Path(scene_path(scene)).stem for scene in cfg.scenes}
    md_f, csv_f = failure_table(rows, metas, cfg, stems)
    put('failures.md', '# How the trials failed\n\n'
        'Per cell: trials that failed because every goal pose was blocked (GOAL_IN_COLLISION or '
        'no IK solution), ran out of time, or failed otherwise; "Goal valid": of the task\'s '
        'fixed goal samples valid without the boxes, the mean fraction still valid with them '
        f'(goal policy {cfg.goal_policy}).\n\n' + md_f)
    put('failures.csv', csv_f)
    md_h, csv_h = hardness_table(rows, metas, cfg, stems)
    put('hardness.md', '# Hardness beyond PSR\n\n'
        'PSR@t: share of trials whose first exact solution came within t seconds of the request '
        f'(read off the {cfg.time_budget_s:g} s runs); T1st: time to first solution, failures '
        'counted at the budget; PT ratio: attacked / unattacked median T1st; Solvable: the '
        'attacks\' verdicts (certified / goal blocked / unknown). "+": the trials did not '
        'report their first-solution time, their planning time (an upper bound) stands in.\n\n'
        + md_h)
    put('hardness.csv', csv_h)

    # Figures: PSR vs budget and time to first solution per scene; heatmap slice + obstacles.
    by_cell: dict[tuple, list] = {}
    for rec in store.records.values():
        by_cell.setdefault((rec['scene'], rec['planner'], rec['method'], int(rec['budget'])),
                           []).append(rec)
    for i, scene in enumerate(cfg.scenes):
        curves = {}
        for planner in cfg.planners:
            base = rows.get((scene, planner, BASELINE, 0))
            for method in cfg.methods:
                pts = {b: rows[(scene, planner, method, b)]['psr'] for b in cfg.all_budgets
                       if (scene, planner, method, b) in rows}
                if pts and base is not None:
                    pts[0] = base['psr']
                if pts:
                    curves[(planner, method)] = pts
        stem = pathlib.Path(scene_path(scene)).stem
        if curves:
            name = f'figures/psr_vs_budget_{stem}.png'
            figures.plot_psr_vs_budget(curves, run_dir / name,
                                       title=f'Scene {i + 1} ({stem}): PSR vs budget')
            out[name] = run_dir / name
        times = {(p, m, b): solution_times(recs)[0] for (sc, p, m, b), recs in by_cell.items()
                 if sc == scene}
        if times:
            name = f'figures/time_to_solution_{stem}.png'
            figures.plot_time_to_solution(
                times, cfg.time_budget_s, run_dir / name,
                title=f'Scene {i + 1} ({stem}): trials solved vs time to first solution')
            out[name] = run_dir / name
        if scene in heatmaps:
            attack_files = sorted((run_dir / 'attacks' / stem).glob('*.yaml'))
            pick = None
            for method in ['task', 'ours'] + list(cfg.methods):
                cands = [(m['budget'], m['path']) for m in metas
                         if m['path'] in attack_files and m.get('method') == method]
                if cands:
                    pick = max(cands, key=lambda c: c[0])[1]
                    break
            try:
                scene_obj = load_scene(scene_path(scene))
                obstacles = load_obstacles(pick)[0] if pick else ()
            except SceneError as exc:
                log.warning('figure of %s: %s', scene, exc)
                continue
            at = list(obstacles[0].shapes[0].pose.position_m) if obstacles else None
            name = f'figures/heatmap_{stem}.png'
            plot_heatmap_slices(heatmaps[scene], run_dir / name, scene=scene_obj,
                                obstacles=obstacles, at_m=at)
            out[name] = run_dir / name
    if summary is not None:
        put('summary.json', json.dumps(summary, indent=2) + '\n')
    return out
