"""File families: our scene YAML, MotionBenchMaker scene and request YAML, obstacles files,
heatmap ``.npz`` files and PLY/PCD clouds; each input is generated from ``(seed, family, index)``.

The pool's target: :func:`setup` once per worker, :func:`run` per input. :func:`generate`
alone (no parser, no robot) rebuilds an input so the driver can write out a crash or hang.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import random
import shutil
import tempfile
import warnings
from typing import Any, Callable

import numpy as np
import yaml

from fuzz import clouds, heatmaps
from fuzz.classify import classify_exception, describe
from fuzz.mutate import hostile_yaml, mutate_bytes, mutate_doc, mutate_text

REPO = pathlib.Path(__file__).resolve().parents[2]
SCENES = REPO / 'config' / 'scenes'
MBM = REPO / 'test' / 'data' / 'mbm'
CLOUD_ENTRY = 'scene.yaml.objects[0]'
"""What a scene file's cloud object is called in errors (the cloud file's path may stand in)."""


_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


@dataclasses.dataclass
class Input:
    """One generated file: its name, bytes, and whether a parser must refuse it."""

    name: str
    data: bytes
    must_refuse: bool = False
    canary: str | None = None
    """A path that exists afterwards only if the parser ran code the file smuggled in."""


def _yaml_texts(paths) -> list[tuple[str, Any]]:
    return [(p.read_text(), yaml.safe_load(p.read_text())) for p in sorted(paths)]


def _obstacles_doc() -> dict:
    from advocc_ros.attack import AttackResult, AttackStatus, obstacles_data
    from advocc_ros.model.scene import make_box
    boxes = tuple(make_box(f'adv_{i}', (0.5, 0.1 * i, 0.3), (0.05,) * 3) for i in range(3))
    return obstacles_data(AttackResult(AttackStatus.SUCCESS, 'placed 3 boxes', boxes,
                                       (1.0, 0.5, 0.25), 1.75, 0.01, 'ours', 3, 0.05))


def bases(context: dict) -> dict:
    """The valid inputs every mutation starts from."""
    obstacles = _obstacles_doc()
    return {
        'scene_yaml': _yaml_texts(SCENES.glob('*.yaml')),
        'mbm_scene': _yaml_texts(list(MBM.glob('scene*.yaml'))
                                 + list(MBM.glob('families/*/scene*.yaml'))),
        'mbm_request': _yaml_texts(list(MBM.glob('request*.yaml'))
                                   + list(MBM.glob('families/*/request*.yaml'))),
        'obstacles': [(yaml.safe_dump(obstacles, sort_keys=False), obstacles)],
        'heatmap': pathlib.Path(context['heatmap']).read_bytes(),
    }


def _yaml_input(rng: random.Random, docs: list[tuple[str, Any]], key: str) -> Input:
    text, doc = rng.choice(docs)
    r = rng.random()
    if r < 0.55:
        out = yaml.dump(mutate_doc(rng, doc), Dumper=_DUMPER, allow_unicode=True,
                        default_flow_style=rng.random() < 0.3).encode()
    elif r < 0.75:
        out = mutate_text(rng, text).encode('utf-8', 'surrogatepass')
    elif r < 0.93:
        out = mutate_bytes(rng, text.encode())
    else:
        out = hostile_yaml(rng, key).encode('utf-8', 'surrogatepass')
    return Input('input.yaml', out)


GENERATORS: dict[str, Callable[[random.Random, dict], Input]] = {
    'scene_yaml': lambda rng, b: _yaml_input(rng, b['scene_yaml'], 'objects'),
    'mbm_scene': lambda rng, b: _yaml_input(rng, b['mbm_scene'], 'world'),
    'mbm_request': lambda rng, b: _yaml_input(rng, b['mbm_request'], 'goal_constraints'),
    'obstacles': lambda rng, b: _yaml_input(rng, b['obstacles'], 'objects'),
    'cloud_ply': lambda rng, b: Input('input.ply', clouds.ply(rng)),
    'cloud_pcd': lambda rng, b: Input('input.pcd', clouds.pcd(rng)),
}
FAMILIES = tuple(GENERATORS) + ('heatmap',)


def generate(family: str, index: int, seed: int, base: dict, workdir: pathlib.Path) -> Input:
    """Input ``index`` of ``family``: the same bytes on every call with the same seed."""
    rng = random.Random(f'{seed}:{family}:{index}')
    if family == 'heatmap':
        canary = workdir / f'pickle_ran_{index}'
        data, must_refuse, smuggled = heatmaps.generate(rng, base['heatmap'], canary)
        return Input('input.npz', data, must_refuse, str(canary) if smuggled else None)
    return GENERATORS[family](rng, base)


# --------------------------------------------------------------------------------------------
# Parsing, in the worker

def setup(context: dict) -> dict:
    from advocc_ros.model.robot import load_robot
    warnings.simplefilter('ignore')  # numpy/trimesh warn about the garbage they are fed
    robot = load_robot()
    workdir = pathlib.Path(tempfile.mkdtemp(prefix='fuzz_', dir=context['tmp']))
    base = bases(context)
    return dict(context, base=base, robot=robot, workdir=workdir,
                robot_hash=heatmaps.robot_hash_of(base['heatmap']))


def _parse(family: str, path: pathlib.Path, state: dict, rng: random.Random) -> str | None:
    """Parse ``path`` as ``family``; returns why an accepted result is wrong, or None."""
    from advocc_ros.model.pose import Pose
    if family == 'scene_yaml':
        from advocc_ros.model.scene import load_scene
        load_scene(path)
    elif family == 'mbm_scene':
        from advocc_ros.formats.mbm_scene import load_mbm_scene
        load_mbm_scene(path)
    elif family == 'mbm_request':
        from advocc_ros.formats.mbm_scene import load_request
        req = load_request(path, state['robot'])
        if req.goal is not None and set(req.goal) != set(state['robot'].joint_names):
            return f'joint goal over {sorted(req.goal)}'
    elif family == 'obstacles':
        from advocc_ros.attack import load_obstacles
        objects, meta = load_obstacles(path)
        if not isinstance(meta, dict) or not all(o.shapes for o in objects):
            return 'object without shapes'
    elif family == 'heatmap':
        from advocc_ros.heatmap import load_heatmap
        h = load_heatmap(path, robot_hash=rng.choice([None, state['robot_hash'], 'other']))
        return heatmaps.check(h)
    else:
        from advocc_ros.model.cloud import cloud_octree, cloud_shape_from_data
        resolution = rng.choice([0.02] * 6 + [0.005, 0.1, 0.0, -1, float('nan'), 'x', 1e9])
        shape = cloud_shape_from_data({'file': path.name, 'resolution': resolution},
                                      CLOUD_ENTRY, path.parent, Pose())
        if not np.all(np.isfinite(shape.vertices)):
            return 'non-finite points'
        cloud_octree(shape)
    return None


def run(state: dict, job: tuple[str, int]) -> tuple[str, str]:
    """Generate, write and parse one input; its category and a short detail."""
    from advocc_ros.heatmap import HeatmapError
    from advocc_ros.model.pose import SceneError
    family, index = job
    item = generate(family, index, state['seed'], state['base'], state['workdir'])
    folder = state['workdir'] / f'{family}_{index}'
    folder.mkdir()
    path = folder / item.name
    path.write_bytes(item.data)
    documented = (HeatmapError,) if family == 'heatmap' else (SceneError,)
    try:
        problem = _parse(family, path, state, random.Random(f'{state["seed"]}:parse:{index}'))
    except BaseException as exc:
        names = (str(path), path.name, CLOUD_ENTRY)
        category, detail = classify_exception(exc, documented, names), describe(exc)
    else:
        category = 'accepted_bad' if (problem or item.must_refuse) else 'ok'
        detail = problem or ('accepted an input that must be refused' if item.must_refuse
                             else '')
    if item.canary and os.path.exists(item.canary):
        category, detail = 'accepted_bad', 'a pickled payload ran'
    shutil.rmtree(folder, ignore_errors=True)
    return category, detail
