"""Make the golden boxes of test/test_attack_regression.py: the boxes the ``task`` attack
places on the five shipped scenes and on problem 0001 of each MotionBenchMaker family
(test/data/mbm_real), pinned bit for bit so that a change that should not move a box (a
refactoring) proves it does not.

Inputs, kept beside this script:

- ``witnesses/<task>.yaml``: each task's candidate witnesses (the witness search's candidate file,
  ``planning.witness_cache`` format ``advocc_witness_candidates``). The search is a timed planner
  run and not reproducible, so its result is data here, handed to ``attack(..., witness=...)``.
- the heatmaps are built by the test itself: robot-only, ``HEATMAP_SAMPLES`` samples from
  ``HEATMAP_SEED`` (seeded and deterministic), one per robot (the shipped Panda and the
  MotionBenchMaker Panda differ in their locked finger values).

Output: ``golden.json``, the cases (task, method, policy, seed, budget) and for each the status,
the box centres (JSON floats: ``repr``, exact) and the marginal masses.

Bit for bit holds on one kind of CPU. numpy, OpenBLAS and glibc's libm (which the kernels, built
for the architecture's baseline, call) pick code paths by the CPU's vector instructions, and
their last bits differ, so a borderline decision (an IK
attempt's convergence, a goal sample's contact with a box) can go the other way: MotionBenchMaker
table_pick's ``reachable`` case at seed 1 places boxes 8 and 10 of 10 one voxel apart on the
Intel Xeon the reference was made on and on an AVX2 AMD EPYC, with equal masses (higher-scored
candidates are passed over by the goal guard's checks, and a different one on each CPU).
A case the reference CPU and another disagree on holds that CPU's boxes under ``by_platform``
(:func:`fp_platform`), added by ``--add-platform`` on that CPU.

Regenerate (from the repository root, only when a change is meant to move the boxes):

    PYTHONPATH=$PWD .venv/bin/python test/data/attack_regression/make_golden.py

on a CPU of another kind (:func:`fp_platform`), to pin its boxes beside the reference's:

    PYTHONPATH=$PWD .venv/bin/python test/data/attack_regression/make_golden.py --add-platform

and, to search the witnesses of the tasks that have no ``witnesses/<task>.yaml`` (delete a file to
search that task again; a planner run, and new witnesses change the inputs, so the boxes of its
``solvable`` cases may move):

    PYTHONPATH=$PWD .venv/bin/python test/data/attack_regression/make_golden.py --search-witnesses

A task whose search finds no witness (MotionBenchMaker's cage problem 0001: RRTConnect finds no
path within the search's budget) has no file; its cases run under ``paper`` instead (and one
``solvable`` case pins the ``no_witness`` answer).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parents[2]
SHIPPED = ('table_pick', 'table_under_pick', 'bookshelf', 'box', 'cage')
FAMILIES = ('bookshelf_small_panda', 'bookshelf_tall_panda', 'bookshelf_thin_panda', 'box_panda',
            'cage_panda', 'table_pick_panda', 'table_under_pick_panda')
HEATMAP_SAMPLES = 1000
HEATMAP_SEED = 0
BUDGET = 10
SEEDS = (0, 1)
OTHER_POLICIES = (('paper', 'table_pick', 0), ('paper', 'mbm_box_panda', 1),
                  ('reachable', 'bookshelf', 0), ('reachable', 'mbm_table_pick_panda', 1))
"""(policy, task, seed) of the cases beside the ``solvable`` ones."""
FORMAT = 'advocc_attack_regression_1'


def tasks() -> dict:
    """Task name -> (scene path, request path or None), relative to the repository root."""
    out = {name: (f'config/scenes/{name}.yaml', None) for name in SHIPPED}
    for family in FAMILIES:
        folder = f'test/data/mbm_real/{family}'
        out[f'mbm_{family}'] = (f'{folder}/scene0001.yaml', f'{folder}/request0001.yaml')
    return out


def load_task(scene: str, request: str | None):
    """(scene, robot, q_init) of one task; a MotionBenchMaker request's joint goal in the
    region form (the paper's, which these cases pin)."""
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot

    loaded = load_any_scene(REPO / scene, REPO / request if request else None,
                            goal_form='region' if request else None)
    robot = load_robot(loaded.robot)
    return loaded, robot, start_configuration(loaded, robot)


def robot_heatmap(scene):
    """The robot-only heatmap of ``scene``'s robot (the objects play no part)."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap

    return build_heatmap(scene, HeatmapConfig(samples=HEATMAP_SAMPLES, robot_only=True),
                         seed=HEATMAP_SEED)


def fp_platform() -> str:
    """The widest x86 vector extension of this CPU (``/proc/cpuinfo``): what numpy, OpenBLAS
    and libm choose their floating-point code paths by; another machine's ISA name, or
    ``unknown``."""
    try:
        flags = set(pathlib.Path('/proc/cpuinfo').read_text().split('flags', 1)[1]
                    .split('\n', 1)[0].split())
    except (OSError, IndexError):
        import platform
        return platform.machine() or 'unknown'
    return next((f for f in ('avx512f', 'avx2', 'avx', 'sse2') if f in flags), 'unknown')


def expected(case: dict, platform: str) -> dict:
    """What ``case`` must give on ``platform``: its own boxes there, else the reference's."""
    return case.get('by_platform', {}).get(platform, case)


def outcomes(case: dict) -> list:
    """Every CPU's pinned boxes for ``case``: the reference's, then ``by_platform``'s."""
    return [case] + list(case.get('by_platform', {}).values())


def outcome(result) -> dict:
    """The golden fields of an attack's result."""
    return {'status': result.status.value,
            'centers': [[float(x) for x in c] for c in result.centers_m],
            'masses': [float(m) for m in result.masses]}


def witness_path(task: str) -> pathlib.Path:
    return HERE / 'witnesses' / f'{task}.yaml'


def cases() -> list[dict]:
    """The ``solvable`` cases of every task with a witness (``paper`` without one), then
    ``OTHER_POLICIES``."""
    out = []
    for task in tasks():
        policy = 'solvable' if witness_path(task).is_file() else 'paper'
        out += [{'task': task, 'method': 'task', 'policy': policy, 'seed': seed,
                 'budget': BUDGET} for seed in SEEDS]
        if policy == 'paper':
            out.append({'task': task, 'method': 'task', 'policy': 'solvable', 'seed': 0,
                        'budget': BUDGET})
    out += [{'task': task, 'method': 'task', 'policy': policy, 'seed': seed, 'budget': BUDGET}
            for policy, task, seed in OTHER_POLICIES]
    return out


def read_witnesses(path: pathlib.Path) -> tuple:
    """The candidate witnesses of a file written by :func:`search_witnesses` (none without)."""
    from advocc_ros.planning.witness_cache import load_candidates

    return load_candidates(path) if path.is_file() else ()


def search_witnesses() -> None:
    """Search the candidate witnesses, on the unattacked scene, of every task without a file,
    and write them."""
    from advocc_ros.planning.witness_cache import find_witnesses, save_candidates

    for name, (scene_path, request) in tasks().items():
        if witness_path(name).is_file():
            continue
        scene, robot, q_init = load_task(scene_path, request)
        witnesses = find_witnesses(robot, scene.objects, q_init, scene.goal)
        if not witnesses:
            print(f'{name}: the witness search found no witness', flush=True)
            continue
        save_candidates(witness_path(name), witnesses)
        print(f'{name}: {len(witnesses)} candidate witnesses', flush=True)


def run_case(case: dict, loaded: dict, heatmaps: dict):
    """The attack of one case (no verdict: it does not move a box)."""
    from advocc_ros.attack import attack

    scene, robot, q_init = loaded[case['task']]
    witnesses = read_witnesses(witness_path(case['task']))
    return attack(heatmaps[robot.hash], robot, scene.objects, q_init, scene.goal,
                  case['budget'], case['method'], goal_policy=case['policy'], seed=case['seed'],
                  witness=witnesses, certify=False)


def load_inputs() -> tuple[dict, dict]:
    """Task name -> (scene, robot, q_init); robot hash -> its robot-only heatmap."""
    loaded = {name: load_task(*paths) for name, paths in tasks().items()}
    heatmaps = {}
    for scene, robot, _ in loaded.values():
        if robot.hash not in heatmaps:
            heatmaps[robot.hash] = robot_heatmap(scene)
    return loaded, heatmaps


def make_golden() -> dict:
    loaded, heatmaps = load_inputs()
    out = []
    for case in cases():
        result = run_case(case, loaded, heatmaps)
        out.append(dict(case, **outcome(result)))
        print(f'{case["task"]} {case["policy"]} seed {case["seed"]}: {result.status.value}, '
              f'{len(result.obstacles)} boxes', flush=True)
    return {'format': FORMAT, 'tasks': {k: {'scene': s, 'request': r}
                                        for k, (s, r) in tasks().items()},
            'heatmap': {'samples': HEATMAP_SAMPLES, 'seed': HEATMAP_SEED, 'robot_only': True},
            'cases': out}


def same(got: dict, want: dict) -> bool:
    """The test's comparison: status and centres exact, masses to 1e-9 (their sums' order may
    differ in the last bits)."""
    import numpy as np

    return (got['status'] == want['status'] and got['centers'] == want['centers']
            and len(got['masses']) == len(want['masses'])
            and bool(np.allclose(got['masses'], want['masses'], rtol=1e-9, atol=1e-12)))


def add_platform(golden: dict) -> dict:
    """``golden`` with this CPU's boxes under ``by_platform`` for every case where they are not
    the reference's (an entry for this CPU that is the reference's is dropped)."""
    loaded, heatmaps = load_inputs()
    platform = fp_platform()
    for case in golden['cases']:
        got = outcome(run_case(case, loaded, heatmaps))
        others = {k: v for k, v in case.get('by_platform', {}).items() if k != platform}
        if not same(got, case):
            others[platform] = got
            print(f'{case["task"]} {case["policy"]} seed {case["seed"]}: other boxes on '
                  f'{platform}', flush=True)
        case.pop('by_platform', None)
        if others:
            case['by_platform'] = others
    return golden


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--search-witnesses', action='store_true',
                        help='search the witnesses again (a planner run) before the boxes')
    parser.add_argument('--add-platform', action='store_true',
                        help=f'pin the boxes of this CPU ({fp_platform()}) where they are not '
                        'the reference\'s, keeping the reference')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='advocc_golden_') as cache:
        os.environ['ADVOCC_WITNESS_CACHE'] = cache  # neither read nor fill the user's cache
        if args.search_witnesses:
            search_witnesses()
        golden = (add_platform(json.loads((HERE / 'golden.json').read_text()))
                  if args.add_platform else make_golden())
    text = json.dumps(golden, indent=1) + '\n'
    (HERE / 'golden.json').write_text(text)
    print(f'wrote {HERE / "golden.json"}: {len(golden["cases"])} cases')
    return 0


if __name__ == '__main__':
    sys.path.insert(0, str(REPO))
    sys.exit(main())
