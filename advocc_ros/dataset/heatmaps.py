"""The robot-only heatmaps of a data set: built once per robot, used by every problem.

The ``task`` attack weighs the task's own configurations; of the heatmap it uses the voxel grid
and the search region (``attack.region``: candidate box centres are voxels with heatmap mass
inside the task's corridor, in free space, clear of the start and the goal region). A robot-only
heatmap (the scene ignored offline, the current scene's voxels masked by the attack) gives that
region for any scene of the robot, which is the paper's amortisation: one offline build per
robot, not per problem. MotionBenchMaker's Panda problems share one robot (the fingers locked
at the same value), so a build over them needs one heatmap; a problem whose locked joints differ
gets its own. Each is saved as ``OUT/heatmaps/robot-<hash>.npz`` and read again on resume. A
heatmap file given instead is part of the build's settings by its content (SHA-256), not its
path: a resume must give the same heatmap, wherever it lies.
"""

from __future__ import annotations

import hashlib
import logging
import pathlib

from advocc_ros.dataset.problems import DatasetError

log = logging.getLogger(__name__)

HEATMAP_DIR = 'heatmaps'


def file_sha256(path: str | pathlib.Path) -> str:
    """The SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, 'rb') as handle:
        for block in iter(lambda: handle.read(1 << 20), b''):
            digest.update(block)
    return digest.hexdigest()


def heatmap_path(out: pathlib.Path, robot_hash: str) -> pathlib.Path:
    """Where the robot-only heatmap of a robot is built to."""
    return out / HEATMAP_DIR / f'robot-{robot_hash}.npz'


def heatmap_settings(samples: int, seed: int, given_sha256: str | None) -> dict:
    """What the heatmaps of a build depend on (part of the settings a resume must share): a
    given file's content, or the robot-only builds' samples and seed."""
    if given_sha256:
        return {'sha256': given_sha256}
    return {'robot_only': True, 'samples': samples, 'seed': seed}


def load_given(path: str):
    """The robot-only heatmap of the file ``path``; ``DatasetError`` for a file that is not
    one (nothing written)."""
    from advocc_ros.heatmap import HeatmapError, load_heatmap

    try:
        heatmap = load_heatmap(path)
    except HeatmapError as exc:
        raise DatasetError(str(exc)) from None
    if not heatmap.robot_only:
        raise DatasetError(f'{path}: a scene-conditioned heatmap fits one scene; give a '
                           'robot-only one (advocc heatmap build --robot-only) or none')
    return heatmap


def robot_heatmaps(scenes: list, out: pathlib.Path, samples: int, seed: int,
                   given=None, workers: int = 1, echo=None) -> dict:
    """``{robot hash: Heatmap}`` for the robots of ``scenes``: ``given`` (a robot-only heatmap,
    ``load_given``) for all, else one robot-only build per robot, saved under ``out/heatmaps``
    (and read from there again when it was built with these settings)."""
    from advocc_ros.heatmap import HeatmapConfig, HeatmapError, build_heatmap, load_heatmap
    from advocc_ros.heatmap import save_heatmap
    from advocc_ros.model.robot import load_robot

    if given is not None:
        return {given.meta.get('robot_hash'): given}
    found: dict = {}
    for scene in scenes:
        robot = load_robot(scene.robot)
        if robot.hash in found:
            continue
        path = heatmap_path(out, robot.hash)
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


__all__ = ['HEATMAP_DIR', 'file_sha256', 'heatmap_path', 'heatmap_settings', 'load_given',
           'robot_heatmaps']
