"""The witness search, cached: ``find_witnesses`` searches a task's candidate witnesses once
(``planning.witness.search_witnesses``) and keeps them in this process and on disk
(``model.cache.disk_cache_dir``), one file a task with the digest of what their certificate
proved.

A later process (another ``advocc attack``, a restarted node) reads the file instead of
searching. When the digest (``proof_digest``: the task's key, the certificate's settings, each
path's content) matches the paths read, they are used as they are; otherwise (a damaged file, an
earlier version's, other settings) each is certified again on the unattacked scene from the
task's start, so such a file costs a search, never a wrong verdict: a verdict is the
certificate's on the attacked scene, made anew by every attack (``attack.solvable.assess``).
A failed search is not kept: the next call searches again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import pathlib

import numpy as np

from advocc_ros.model.cache import BoundedCache, disk_cache_dir
from advocc_ros.model.collision import CollisionWorld
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import SceneError
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import SceneObject, read_yaml, save_yaml_atomic, task_hash
from advocc_ros.planning.certificate import CertificateConfig
from advocc_ros.planning.direct_motion import DIRECT_BLOCK_M, direct_blocker
from advocc_ros.planning.witness import (END_CANDIDATES, END_CLEARANCE_M, END_TIME_S,
                                         WITNESS_PLANNER, WITNESS_SEED, WITNESS_STEP_RAD,
                                         WITNESS_TIME_S, WITNESS_TRIES, Witness, certify,
                                         grown_objects, search_witnesses)

log = logging.getLogger(__name__)

SET_FORMAT = 'advocc_witness_candidates'
"""The file: ``{format, witnesses: [witness data, ...], proof_digest}``."""


WITNESSES: BoundedCache = BoundedCache('witnesses', 32)
"""Task hash -> the candidate witnesses found in this process (a failed search is not kept)."""


def find_witnesses(robot: RobotModel, objects: tuple[SceneObject, ...] | list,
                   q_init: np.ndarray, goal: GoalRegion, time_s: float = WITNESS_TIME_S,
                   clearance_m: float = 0.0) -> tuple[Witness, ...]:
    """The task's candidate witnesses on the scene ``objects``, each certified there (empty
    when the search found none), planned ``clearance_m`` clear of its primitives when it can
    be and around the direct motion's cube when there is one (``planning.direct_motion``), cached
    per task in this process and on disk (module docstring)."""
    objects = tuple(objects)
    q_init = np.asarray(q_init, float)
    world = CollisionWorld(robot, [sh for o in objects for sh in o.shapes])
    blocker = direct_blocker(robot, world, q_init, goal, WITNESS_STEP_RAD)
    key = task_hash(robot.hash, objects, goal, np.round(q_init, 12).tolist(), time_s,
                    SET_FORMAT, WITNESS_PLANNER, WITNESS_SEED, WITNESS_STEP_RAD,
                    'continuous', WITNESS_TRIES, END_CANDIDATES, END_CLEARANCE_M, END_TIME_S,
                    *(('clearance', clearance_m) if clearance_m > 0 else ()),
                    *(('direct blocker', list(blocker.shapes[0].pose.position_m), DIRECT_BLOCK_M)
                      if blocker is not None else ()))
    cached = WITNESSES.get(key)
    if cached is not None:
        return cached
    cache_dir = disk_cache_dir()
    disk = cache_dir / f'{key}.yaml' if cache_dir is not None else None
    witnesses = _from_disk(disk, key, robot, world, q_init, goal) if disk is not None else ()
    searched = not witnesses
    for planned_among in _search_scenes(objects, clearance_m, blocker):
        if witnesses:
            break
        witnesses = search_witnesses(robot, world, objects, q_init, goal, time_s, planned_among)
        if blocker is not None and blocker.id in (o.id for o in planned_among):
            witnesses = tuple(dataclasses.replace(w, source=dict(
                w.source, direct_blocker_center_m=list(blocker.shapes[0].pose.position_m)))
                for w in witnesses)
    if not witnesses:  # not kept: a later call searches again
        return ()
    if disk is not None and searched:
        _to_disk(disk, key, witnesses)
    return WITNESSES.put(key, witnesses)


def _search_scenes(objects: tuple[SceneObject, ...], clearance_m: float,
                   blocker: SceneObject | None) -> list[tuple[SceneObject, ...]]:
    """The scenes the search plans among, in the order tried: with the direct motion's blocker
    (when there is one) before without, the scene grown by ``clearance_m`` (when > 0) before
    the scene as it is."""
    scenes = []
    for extra in ((blocker,), ()) if blocker is not None else ((),):
        if clearance_m > 0:
            scenes.append(grown_objects(objects + extra, clearance_m))
        scenes.append(objects + extra)
    return scenes


def save_candidates(path: str | pathlib.Path, witnesses: tuple[Witness, ...],
                    digest: str | None = None) -> None:
    """Write candidate witnesses atomically (``{format: SET_FORMAT, witnesses: [...]}``, the
    disk cache's file), with ``digest`` (``proof_digest``) when they were certified."""
    data = {'format': SET_FORMAT, 'witnesses': [w.to_data() for w in witnesses]}
    save_yaml_atomic(path, data if digest is None else dict(data, proof_digest=digest))


def proof_digest(key: str, witnesses: tuple[Witness, ...]) -> str:
    """What certifying ``witnesses`` for the task of ``key`` (``find_witnesses``'s cache key)
    proved, as a digest: the key, the certificate's settings and each path's content."""
    text = json.dumps([key, dataclasses.asdict(CertificateConfig()),
                       [w.content_hash() for w in witnesses]], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def load_candidates(path: str | pathlib.Path) -> tuple[Witness, ...]:
    """The candidate witnesses of a file written by :func:`save_candidates`; ``SceneError``
    naming the file (and the field) when it is not one, ``OSError`` when it cannot be read."""
    return _read_candidates(path)[0]


def _read_candidates(path: str | pathlib.Path) -> tuple[tuple[Witness, ...], str | None]:
    """``load_candidates``'s witnesses and the file's ``proof_digest`` (None without one)."""
    data = read_yaml(pathlib.Path(path))
    if not isinstance(data, dict) or data.get('format') != SET_FORMAT or \
            not isinstance(data.get('witnesses'), list) or not data['witnesses']:
        raise SceneError(f'{path}: not a {SET_FORMAT} file')
    digest = data.get('proof_digest')
    return tuple(Witness.from_data(w, f'{path}: witnesses[{i}]')
                 for i, w in enumerate(data['witnesses'])), \
        digest if isinstance(digest, str) else None


def _from_disk(path: pathlib.Path, key: str, robot: RobotModel, world: CollisionWorld,
               q_init: np.ndarray, goal: GoalRegion) -> tuple[Witness, ...]:
    """The cached candidates of ``path`` (the task of ``key``) if every one is a witness of
    this task (their ``proof_digest`` as written, or certified again, and then the file
    written with it); else none."""
    if not path.is_file():
        return ()
    try:
        witnesses, digest = _read_candidates(path)
    except (SceneError, OSError) as exc:
        log.warning('witness cache: %s (searching again)', exc)
        return ()
    if digest == proof_digest(key, witnesses):
        return witnesses
    for witness in witnesses:
        why = certify(robot, world, goal, witness, q_init).why
        if why is not None:
            log.warning('witness cache: %s is not a witness of this task: %s (searching '
                        'again)', path, why)
            return ()
    _to_disk(path, key, witnesses)
    return witnesses


def _to_disk(path: pathlib.Path, key: str, witnesses: tuple[Witness, ...]) -> None:
    """Keep the certified candidates of the task of ``key`` in ``path``."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_candidates(path, witnesses, proof_digest(key, witnesses))
    except OSError as exc:  # a read-only home must not fail the attack
        log.warning('witness cache: cannot write %s (%s)', path, exc)


__all__ = ['SET_FORMAT', 'WITNESSES', 'find_witnesses', 'load_candidates', 'proof_digest',
           'save_candidates']
