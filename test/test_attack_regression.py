"""The ``task`` attack's boxes, bit for bit: the five shipped scenes and problem 0001 of each
MotionBenchMaker family, at seeds 0 and 1, under ``solvable`` (and a few ``paper`` and
``reachable`` cases), M = 10. The witnesses (a timed planner run, not reproducible) and the
expected boxes are data in test/data/attack_regression, made by its ``make_golden.py`` (its
docstring says when and how to make them again); the heatmaps are small robot-only builds,
seeded, made once here. A change that moves one box fails its case. Bit for bit holds on one
kind of CPU: a case whose boxes differ on another kind holds that kind's too (``by_platform``,
``make_golden.fp_platform``), and any CPU's pinned boxes pass (the ISA does not tell every kind
apart: the AVX-512 AMD EPYC places table_pick's ``reachable`` seed-1 boxes as the AVX2 one does,
the AVX-512 Xeon of the reference does not)."""

import importlib.util
import json
import pathlib

import pytest

pytestmark = pytest.mark.slow

DATA = pathlib.Path(__file__).resolve().parent / 'data' / 'attack_regression'
_spec = importlib.util.spec_from_file_location('make_golden', DATA / 'make_golden.py')
golden_maker = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(golden_maker)
GOLDEN = json.loads((DATA / 'golden.json').read_text())
CASES = GOLDEN['cases']


def test_the_golden_file_is_the_makers():
    """The file holds the maker's cases with its heatmap settings: regenerated, not edited."""
    assert GOLDEN['format'] == golden_maker.FORMAT
    assert GOLDEN['heatmap'] == {'samples': golden_maker.HEATMAP_SAMPLES,
                                 'seed': golden_maker.HEATMAP_SEED, 'robot_only': True}
    keys = ('task', 'method', 'policy', 'seed', 'budget')
    assert [{k: c[k] for k in keys} for c in CASES] == golden_maker.cases()
    assert sum(c['policy'] == 'solvable' and c['status'] == 'success' for c in CASES) >= 20


@pytest.fixture(scope='module')
def tasks():
    """Task name -> (scene, robot, q_init); robot hash -> its robot-only heatmap."""
    loaded = {name: golden_maker.load_task(*paths)
              for name, paths in golden_maker.tasks().items()}
    heatmaps = {}
    for scene, robot, _ in loaded.values():
        if robot.hash not in heatmaps:
            heatmaps[robot.hash] = golden_maker.robot_heatmap(scene)
    return loaded, heatmaps


@pytest.mark.parametrize('case', CASES,
                         ids=[f'{c["task"]}-{c["policy"]}-seed{c["seed"]}' for c in CASES])
def test_the_boxes_are_the_golden_ones(case, tasks):
    want = golden_maker.expected(case, golden_maker.fp_platform())
    got = golden_maker.outcome(golden_maker.run_case(case, *tasks))
    if any(golden_maker.same(got, pinned) for pinned in golden_maker.outcomes(case)):
        return  # this CPU's boxes, or another pinned CPU's where the two differ in a tie
    assert got['status'] == want['status']
    assert got['centers'] == want['centers']
    assert got['masses'] == pytest.approx(want['masses'], rel=1e-9, abs=1e-12)
