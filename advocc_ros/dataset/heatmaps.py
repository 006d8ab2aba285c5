"""The robot-only heatmaps of a data set: built once per robot, used by every problem.

The ``task`` attack weighs the task's own configurations; of the heatmap it uses the voxel grid
and the search region (``attack.region``: candidate box centres are voxels with heatmap mass
inside the task's corridor, in free space, clear of the start and the goal region). A robot-only
heatmap (the scene ignored offline, the current scene's voxels masked by the attack) gives that
region for any scene of the robot, which is the paper's amortisation: one offline build per
robot, not per problem. MotionBenchMaker's Panda problems share one robot (the fingers locked
at the same value), so a build over them needs one heatmap; a problem whose locked joints differ
gets its own. Each is saved as ``OUT/heatmaps/robot-<hash>.npz`` and read again on resume.
"""

from __future__ import annotations

import logging
import pathlib

from advocc_ros.dataset.problems import DatasetError

log = logging.getLogger(__name__)

HEATMAP_DIR = 'heatmaps'


def heatmap_settings(samples: int, seed: int, given: str | None) -> dict:
    """What the heatmaps of a build depend on (part of the settings a resume must share)."""
    if given:
        return {'file': str(pathlib.Path(given).resolve())}
    return {'robot_only': True, 'samples': samples, 'seed': seed}


def robot_heatmaps(scenes: list, out: pathlib.Path, samples: int, seed: int,
                   given: str | None = None, workers: int = 1, echo=None) -> dict:
    """``{robot hash: Heatmap}`` for the robots of ``scenes``: ``given`` (a robot-only heatmap
    file) for all, else one robot-only build per robot, saved under ``out/heatmaps``."""
    from advocc_ros.heatmap import HeatmapConfig, HeatmapError, build_heatmap, load_heatmap
    from advocc_ros.heatmap import save_heatmap
    from advocc_ros.model.robot import load_robot

    if given:
        try:
            heatmap = load_heatmap(given)
        except HeatmapError as exc:
            raise DatasetError(str(exc)) from None
        if not heatmap.robot_only:
            raise DatasetError(f'{given}: a scene-conditioned heatmap fits one scene; give a '
                               'robot-only one (advocc heatmap build --robot-only) or none')
        return {heatmap.meta.get('robot_hash'): heatmap}
    found: dict = {}
    for scene in scenes:
        robot = load_robot(scene.robot)
        if robot.hash in found:
            continue
        path = out / HEATMAP_DIR / f'robot-{robot.hash}.npz'
        if path.is_file():
            try:
                heatmap = load_heatmap(path, robot_hash=robot.hash)
                params = heatmap.meta.get('params', {})
                if (heatmap.robot_only and params.get('samples') == samples
                        and heatmap.meta.get('seeds') == [str(seed)]):
                    found[robot.hash] = heatmap
                    continue
            except HeatmapError as exc:
                log.warning('%s: built again (%s)', path, exc)
        if echo:
            echo(f'building the robot-only heatmap of robot {robot.hash} ({samples} samples, '
                 'once for every problem of this robot)')
        heatmap = build_heatmap(scene, HeatmapConfig(samples=samples, robot_only=True), seed,
                                workers=workers)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_heatmap(heatmap, path)
        found[robot.hash] = heatmap
    return found


__all__ = ['HEATMAP_DIR', 'heatmap_settings', 'robot_heatmaps']
