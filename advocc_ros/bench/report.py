"""The run folder's report: tables, figures and summary from its records (no ROS, no nodes)."""

from __future__ import annotations

import json
import logging
import pathlib
from typing import Any

from advocc_ros.attack.obstacles import obstacles_meta
from advocc_ros.bench.protocol import BASELINE, BenchConfig, variation_scenes
from advocc_ros.bench.records import RecordStore
from advocc_ros.bench.tables import (baseline_table, cell_rows, cell_table, failure_table,
                                     hardness_table, table1, table2, table4)
from advocc_ros.evaluation.hardness import solution_times
from advocc_ros.evaluation.outcomes import MAX_INTERNAL_ERROR_FRACTION, too_many_internal_errors
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


def internal_error_summary(rows: dict[tuple, dict]) -> dict[str, Any]:
    """The run summary's ``internal_errors`` (count) and ``reason`` (None, or why the run
    failed: cells with more than ``MAX_INTERNAL_ERROR_FRACTION`` internal errors)."""
    over = [f'{"/".join(map(str, cell))} ({row["internal_errors"]} of {row["trials"]})'
            for cell, row in sorted(rows.items(), key=lambda item: tuple(map(str, item[0])))
            if too_many_internal_errors(row)]
    reason = None
    if over:
        reason = (f'more than {100 * MAX_INTERNAL_ERROR_FRACTION:g} % of the trials were '
                  f'internal errors in {len(over)} cells (scene/planner/method/budget): '
                  + ', '.join(over))
    return {'internal_errors': sum(row['internal_errors'] for row in rows.values()),
            'reason': reason}


class _Files:
    """The report's files, written atomically into the run folder; ``out`` maps name -> path."""

    def __init__(self, run_dir: pathlib.Path):
        self.run_dir = run_dir
        self.out: dict[str, pathlib.Path] = {}

    def put(self, name: str, text: str) -> None:
        atomic_write_text(self.run_dir / name, text)
        self.out[name] = self.run_dir / name

    def path(self, name: str) -> pathlib.Path:
        """Where a figure goes (it writes itself) and note it."""
        self.out[name] = self.run_dir / name
        return self.out[name]


def write_report(run_dir: str | pathlib.Path, cfg: BenchConfig, summary: dict | None = None
                 ) -> dict[str, pathlib.Path]:
    """Tables I, II, IV (+ baseline) as Markdown and CSV, figures, OMPL benchmark logs and the
    Planner Arena database (``bench.arena``), summary; all atomic."""
    run_dir = pathlib.Path(run_dir)
    records = list(RecordStore(run_dir / 'records.jsonl').records.values())
    rows = cell_rows(records, cfg)
    files = _Files(run_dir)
    heatmaps = _load_heatmaps(run_dir, cfg)
    metas = _attack_metas(run_dir)
    _write_tables(files, rows, cfg, metas, {s: h.meta for s, h in heatmaps.items()},
                  (summary or {}).get('notes', []))
    from advocc_ros.paths import scene_path
    stems = {scene: pathlib.Path(scene_path(scene)).stem for scene in cfg.scenes}
    files.put('cells.csv', cell_table(rows, metas, records, cfg, stems, run_dir.resolve().name))
    for i, scene in enumerate(cfg.scenes):
        _write_figures(files, rows, cfg, i, scene, heatmaps.get(scene), metas)
        _write_time_figure(files, records, cfg, i, scene)
    from advocc_ros.bench.arena import write_ompl_results
    files.out.update(write_ompl_results(run_dir, records, cfg))  # Planner Arena, OMPL logs
    if summary is not None:
        files.put('summary.json', json.dumps(summary, indent=2) + '\n')
    return files.out


def _load_heatmaps(run_dir: pathlib.Path, cfg: BenchConfig) -> dict[str, Any]:
    """Each scene's heatmap: the one the run used (config.json) or built into the run folder."""
    from advocc_ros.heatmap import HeatmapError, load_heatmap
    from advocc_ros.paths import scene_path

    try:
        sources = json.loads((run_dir / 'config.json').read_text()).get('heatmaps', {})
    except (OSError, ValueError):
        sources = {}
    heatmaps: dict[str, Any] = {}
    for scene in cfg.scenes:
        built = run_dir / 'heatmaps' / f'{pathlib.Path(scene_path(scene)).stem}.npz'
        files = sources.get(scene) or ([str(built)] if built.exists() else None)
        if not files:
            continue
        try:
            heatmaps[scene] = load_heatmap(files[0])
        except HeatmapError as exc:
            log.warning('heatmap of %s: %s', scene, exc)
    return heatmaps


def _write_tables(files: _Files, rows: dict[tuple, dict], cfg: BenchConfig, metas: list[dict],
                  heatmap_meta: dict[str, dict], notes: list[str]) -> None:
    """Tables I (+ baseline), II, IV and the failure table, Markdown and CSV."""
    from advocc_ros.paths import scene_path

    md1, csv1 = table1(rows, cfg)
    head = (f'Time budget {cfg.time_budget_s:g} s, {cfg.trials} trials per cell planned '
            '(`*`: fewer finished; `!`: some were internal errors, left out of PSR and counted '
            'in failures.md). PSR in %, SMR and CMR x10^-2, JDS in rad, PT in s.\n')
    base = baseline_table(rows, cfg)
    base = f'\n## Unattacked baseline (budget 0)\n\n{base}' if base.count('\n') > 2 else ''
    files.put('table1.md', f'# Table I: attack performance\n\n{head}\n{md1}{base}'
              + ''.join(f'\n- {n}' for n in notes) + ('\n' if notes else ''))
    files.put('table1.csv', csv1)
    md2, csv2 = table2(rows, cfg, variation_scenes(cfg, files.run_dir))
    files.put('table2.md', '# Table II: minimum budget to reach PSR <= threshold\n\n'
              'Smallest measured budget (0 = unattacked) whose PSR is at or below the threshold; '
              '"> M" when the largest measured budget M does not reach it. With variations, the '
              'mean over the scene and its variations ("Tasks") that reach it; "(k/n)": only k '
              'of n do.\n\n' + md2)
    files.put('table2.csv', csv2)
    md4, csv4 = table4(metas, heatmap_meta)
    files.put('table4.md', '# Table IV: offline and online time per method (s)\n\n'
              'Offline: heatmap build (Ours and Task search its H > 0 voxels). Online: core '
              'compute time of one attack, mean over the attacks generated in this run.\n\n'
              + md4)
    files.put('table4.csv', csv4)
    stems = {scene: pathlib.Path(scene_path(scene)).stem for scene in cfg.scenes}
    md_f, csv_f = failure_table(rows, metas, cfg, stems)
    files.put('failures.md', '# How the trials failed\n\n'
              'Per cell: trials that failed because the planner sampled no collision-free goal '
              'configuration (GOAL_IN_COLLISION or no IK solution: whether the goal is really '
              'blocked is the attacks\' solvable verdict in hardness.md), ran out of time, or '
              'failed otherwise, and '
              'the internal errors (the planner raised or died, or returned a colliding path: '
              'not counted in PSR); "Goal valid": of the task\'s fixed goal samples valid '
              'without the boxes, the mean fraction still valid with them (goal policy '
              f'{cfg.goal_policy}).\n\n' + md_f)
    files.put('failures.csv', csv_f)
    md_h, csv_h = hardness_table(rows, metas, cfg, stems)
    files.put('hardness.md', '# Hardness beyond PSR\n\n'
              'PSR@t: share of trials whose first exact solution came within t seconds of the '
              f'request (read off the {cfg.time_budget_s:g} s runs); T1st: time to first '
              'solution, failures counted at the budget; PT ratio: attacked / unattacked median '
              'T1st; Solvable: the attacks\' verdicts (certified / goal blocked / unknown). "+": '
              'the trials did not report their first-solution time, their planning time (an '
              'upper bound) stands in.\n\n' + md_h)
    files.put('hardness.csv', csv_h)


def _psr_curves(rows: dict[tuple, dict], cfg: BenchConfig, scene: str
                ) -> dict[tuple[str, str], dict[int, float | None]]:
    """PSR per budget (0 = unattacked) per (planner, method) of one scene; a cell whose PSR
    is undefined (every trial an internal error) is no point."""
    def psr(cell: tuple) -> float | None:
        return rows[cell]['psr'] if cell in rows else None

    curves = {}
    for planner in cfg.planners:
        base = psr((scene, planner, BASELINE, 0))
        for method in cfg.methods:
            pts = {b: psr((scene, planner, method, b)) for b in cfg.all_budgets}
            pts = {b: value for b, value in pts.items() if value is not None}
            if pts and base is not None:
                pts[0] = base
            if pts:
                curves[(planner, method)] = pts
    return curves


def _figure_attack(run_dir: pathlib.Path, stem: str, metas: list[dict], cfg: BenchConfig
                   ) -> pathlib.Path | None:
    """The attack file the heatmap figure shows: the largest budget of the first method
    (Task, Ours, then the run's) that has one."""
    attack_files = sorted((run_dir / 'attacks' / stem).glob('*.yaml'))
    for method in ['task', 'ours'] + list(cfg.methods):
        cands = [(m['budget'], m['path']) for m in metas
                 if m['path'] in attack_files and m.get('method') == method]
        if cands:
            return max(cands, key=lambda c: c[0])[1]
    return None


def _write_time_figure(files: _Files, records: list[dict], cfg: BenchConfig, index: int,
                       scene: str) -> None:
    """Share of trials solved against time to first solution, one curve per cell of a scene."""
    import advocc_ros.bench.figures as figures
    from advocc_ros.paths import scene_path

    by_cell: dict[tuple, list] = {}
    for rec in records:
        if rec['scene'] == scene:
            by_cell.setdefault((rec['planner'], rec['method'], int(rec['budget'])), []).append(rec)
    if not by_cell:
        return
    stem = pathlib.Path(scene_path(scene)).stem
    figures.plot_time_to_solution(
        {cell: solution_times(recs)[0] for cell, recs in by_cell.items()}, cfg.time_budget_s,
        files.path(f'figures/time_to_solution_{stem}.png'),
        title=f'Scene {index + 1} ({stem}): trials solved vs time to first solution')


def _write_figures(files: _Files, rows: dict[tuple, dict], cfg: BenchConfig, index: int,
                   scene: str, heatmap, metas: list[dict]) -> None:
    """PSR vs budget of one scene (one panel per planner); its heatmap slice with the boxes."""
    import advocc_ros.bench.figures as figures
    from advocc_ros.attack import load_obstacles
    from advocc_ros.evaluation.figures import plot_heatmap_slices
    from advocc_ros.paths import scene_path
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.scene import load_scene

    stem = pathlib.Path(scene_path(scene)).stem
    curves = _psr_curves(rows, cfg, scene)
    if curves:
        figures.plot_psr_vs_budget(curves, files.path(f'figures/psr_vs_budget_{stem}.png'),
                                   title=f'Scene {index + 1} ({stem}): PSR vs budget')
    if heatmap is None:
        return
    pick = _figure_attack(files.run_dir, stem, metas, cfg)
    try:
        scene_obj = load_scene(scene_path(scene))
        obstacles = load_obstacles(pick)[0] if pick else ()
    except SceneError as exc:
        log.warning('figure of %s: %s', scene, exc)
        return
    at = list(obstacles[0].shapes[0].pose.position_m) if obstacles else None
    plot_heatmap_slices(heatmap, files.path(f'figures/heatmap_{stem}.png'),
                        scene=scene_obj, obstacles=obstacles, at_m=at)
