"""The ``task`` attack's options without the Python API: one checker (``task_options``) behind
the CLI's ``--task-option``, the heatmap server's ``task_*`` parameters and the bench's
``task`` setting."""

import dataclasses
import json

import pytest

from advocc_ros.attack.task import OPTION_VALUES, TaskOptions, task_options
from advocc_ros.bench import BenchConfig, BenchError, check_run_config
from advocc_ros.cli import main


def test_a_valid_mapping_gives_the_options_the_rest_default():
    opts = task_options({'detours': 1, 'tube_rad': 1, 'detour_rad': 0.3})
    assert opts == TaskOptions(detours=1, tube_rad=1.0, detour_rad=0.3)
    assert isinstance(opts.tube_rad, float)  # an integer for a real option becomes a float
    assert task_options({}) == TaskOptions()
    assert set(OPTION_VALUES) == {f.name for f in dataclasses.fields(TaskOptions)}


@pytest.mark.parametrize('mapping, words', [
    ({'detourz': 1}, "unknown option 'detourz'; known: approach_goals,"),
    ({'detours': 'many'}, "detours must be an integer >= 0, got 'many'"),
    ({'detours': 2.5}, 'detours must be an integer >= 0, got 2.5'),
    ({'approach_goals': True}, 'approach_goals must be an integer in [0, 1024], got True'),
    ({'tube_rad': [0.1]}, 'tube_rad must be a finite number >= 0'),
    ({'tube_samples': -1}, 'tube_samples must be an integer in [0, 65536], got -1'),
    ({'tube_samples': 10**9}, 'tube_samples must be an integer in [0, 65536], got 1000000000'),
    ({'approach_goals': 1025}, 'approach_goals must be an integer in [0, 1024], got 1025'),
    ({'detours': 10**6}, 'is 256000256 approach configurations; at most 65536'),
    ({'detour_rad': float('nan')}, 'detour_rad must be a finite number >= 0, got nan'),
    ({'pocket_tier': 2}, 'pocket_tier must be 0 or 1, got 2'),
    ({'tube_tier': 2}, 'tube_tier must be 0 or 1, got 2'),
    ({'cut_routes': -1}, 'cut_routes must be 0 or 1, got -1'),
    ({'corridor_routes': 70000}, 'corridor_routes must be an integer in [0, 65536], got 70000'),
    ({'pocket_samples': -5}, 'pocket_samples must be an integer in [0, 65536], got -5'),
    ({'pocket_samples': 65537}, 'pocket_samples must be an integer in [0, 65536], got 65537'),
    ({'pocket_rad': float('inf')}, 'pocket_rad must be a finite number >= 0, got inf'),
    ({'exit_rays': 65537}, 'exit_rays must be an integer in [0, 65536], got 65537'),
    ({'exit_rounds': 9}, 'exit_rounds must be an integer in [0, 8], got 9'),
    ('detours=1', 'expected a mapping of option: value'),
])
def test_unknown_options_wrong_types_and_bad_values_are_refused_by_name(mapping, words):
    with pytest.raises(ValueError) as err:
        task_options(mapping)
    assert words in str(err.value)


def _attack_args(heatmap_file, tmp_path, *more):
    return ['attack', '--heatmap', str(heatmap_file), '--scene', 'table_pick', '--budget', '3',
            '--out', str(tmp_path / 'boxes.yaml'), *more]


@pytest.mark.processes  # the solvable policy's witness search runs in a planning worker
def test_cli_passes_the_options_to_the_attack(heatmap_file, tmp_path, capsys):
    from advocc_ros.attack import load_obstacles

    args = _attack_args(heatmap_file, tmp_path, '--method', 'task', '--policy', 'solvable',
                        '--task-option', 'tube_samples=0', '--task-option', 'detours=0',
                        '--json')
    assert main(args) == 0
    stats = json.loads(capsys.readouterr().out)['stats']
    # no tube, straight approaches only: approach_points per approach goal at most
    opts = TaskOptions(tube_samples=0, detours=0)
    assert 0 < stats['task_approach_samples'] <= opts.approach_goals * opts.approach_points
    _, meta = load_obstacles(tmp_path / 'boxes.yaml')
    assert meta['task_options'] == dataclasses.asdict(opts)


@pytest.mark.parametrize('more, words', [
    (['--method', 'task', '--task-option', 'detours=-1'],
     '--task-option: detours must be an integer >= 0, got -1'),
    (['--method', 'task', '--task-option', 'detourz=1'], "unknown option 'detourz'"),
    (['--method', 'task', '--task-option', 'detours'], 'expected KEY=VALUE'),
    (['--method', 'random', '--task-option', 'detours=1'],
     "--task-option applies to the task method only, not 'random'"),
])
def test_cli_refuses_bad_task_options_before_any_work(heatmap_file, tmp_path, capsys, more,
                                                      words):
    assert main(_attack_args(heatmap_file, tmp_path, *more)) == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / 'boxes.yaml').exists()


@pytest.mark.parametrize('args', [
    ['audit', '--scene', 'table_pick', '--method', 'ours', '--out', 'unused'],
    ['perf', 'attack', '--method', 'ours', '--no-service'],
    ['export', '--scene', 'table_pick', '--obstacles', 'unused.yaml', '--out', 'unused'],
])
def test_every_command_that_attacks_takes_the_option(args, capsys):
    assert main([*args, '--task-option', 'detours=1']) == 2
    err = capsys.readouterr().err
    assert '--task-option applies to' in err, err


def test_bench_task_setting_is_checked_at_load():
    cfg = BenchConfig.from_data({'task': {'detours': 1}})
    assert cfg.task == {'detours': 1}
    for bad, words in (({'detourz': 1}, "unknown option 'detourz'"),
                       ({'detours': -1}, 'detours must be an integer >= 0'),
                       ('detours', 'mapping')):
        with pytest.raises(BenchError, match='bench setting task: ') as err:
            BenchConfig.from_data({'task': bad})
        assert words in str(err.value)


def test_a_run_folder_refuses_other_task_options(tmp_path):
    cfg = BenchConfig(task={'detours': 1})
    (tmp_path / 'config.json').write_text(json.dumps({'config': cfg.to_data()}))
    check_run_config(tmp_path, BenchConfig(task={'detours': 1}))
    with pytest.raises(BenchError, match=r"task: \{'detours': 1\} -> \{\}"):
        check_run_config(tmp_path, BenchConfig())
    # A folder written before the setting existed ran the defaults: it resumes with them.
    old = {k: v for k, v in BenchConfig().to_data().items() if k != 'task'}
    (tmp_path / 'config.json').write_text(json.dumps({'config': old}))
    check_run_config(tmp_path, BenchConfig())
    with pytest.raises(BenchError, match='task: '):
        check_run_config(tmp_path, cfg)


def test_server_parameters_of_the_bench_setting():
    from advocc_ros.nodes.heatmap_server import PARAMETERS, task_parameters

    params = task_parameters({'detours': 1, 'tube_rad': 1})
    assert params == {'task_detours': 1, 'task_tube_rad': 1.0}
    assert isinstance(params['task_tube_rad'], float)  # a ROS double parameter
    declared = {p.name: p.default for p in PARAMETERS}
    for f in dataclasses.fields(TaskOptions):
        assert declared[f'task_{f.name}'] == f.default
    with pytest.raises(ValueError, match='unknown option'):
        task_parameters({'drawz': 1})


def test_the_data_set_closes_a_joint_goals_pocket_first_unless_told_otherwise():
    """``dataset build``'s task options default to ``pocket_tier=1``, ``pocket_samples=4096``,
    ``exit_rays=65536`` and ``exit_rounds=3`` (chosen on the train split; the attack's own
    defaults stay 0, 256, 0 and 0); a given option overrides them, and the attack's defaults
    give the settings of a folder built before."""
    import argparse

    from advocc_ros.commands import dataset

    parser = argparse.ArgumentParser()
    dataset.register(parser.add_subparsers(dest='command'))

    def build_options(*more):
        args = parser.parse_args(['dataset', 'build', '--problems', 'P', '--out', 'O', *more])
        return dict(dataset._config(args)[0].task_options)

    assert TaskOptions().pocket_tier == 0 and TaskOptions().pocket_samples == 256
    assert TaskOptions().exit_rays == 0 and TaskOptions().exit_rounds == 0
    assert TaskOptions().corridor_routes == 0
    built = {'pocket_tier': 1, 'pocket_samples': 4096, 'exit_rays': 65536, 'exit_rounds': 3,
             'corridor_routes': 1024}
    assert build_options() == built
    assert build_options('--task-option', 'detours=0') == dict(built, detours=0)
    assert build_options('--task-option', 'pocket_samples=256') == \
        {'pocket_tier': 1, 'exit_rays': 65536, 'exit_rounds': 3, 'corridor_routes': 1024}
    assert build_options('--task-option', 'pocket_tier=0', '--task-option', 'exit_rays=0',
                         '--task-option', 'pocket_samples=256', '--task-option', 'exit_rounds=0',
                         '--task-option', 'corridor_routes=0') == {}
