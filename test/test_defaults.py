"""Names and numbers with one source: the robot spec names the robot's frames and links, the
heatmap's own parameters weigh the attack's configurations."""

import dataclasses

import numpy as np
import pytest

from advocc_ros.heatmap import HeatmapConfig, build_heatmap
from advocc_ros.heatmap.config import weight_config
from advocc_ros.model.robot import RobotSpec
from advocc_ros.model.scene import scene_from_data

UR5 = {'urdf': 'example-robot-data://ur_description/urdf/ur5_robot.urdf',
       'srdf': 'example-robot-data://ur_description/srdf/ur5.srdf', 'group': '',
       'ee_link': 'tool0', 'base_frame': 'base_link'}
GOAL = {'center': {'position': [0.45, 0.15, 0.3], 'orientation': [1.0, 0.0, 0.0, 0.0]}}


def test_a_scene_without_frame_or_goal_link_takes_them_from_its_robot():
    scene = scene_from_data({'robot': UR5, 'goal': GOAL}, 'ur5.yaml')
    assert scene.frame == 'base_link'
    assert scene.goal.link == 'tool0'
    panda = scene_from_data({'goal': GOAL}, 'panda.yaml')
    assert (panda.frame, panda.goal.link) == (RobotSpec.base_frame, RobotSpec.ee_link)
    named = scene_from_data({'robot': UR5, 'frame': 'world',
                             'goal': {**GOAL, 'link': 'wrist_3_link'}}, 'ur5.yaml')
    assert (named.frame, named.goal.link) == ('world', 'wrist_3_link')


def test_a_goal_message_without_link_takes_the_robots_end_effector():
    from advocc_msgs.msg import GoalRegion as GoalRegionMsg
    from advocc_ros.ros.conversions import goal_region_from_msg
    msg = GoalRegionMsg()
    msg.center.orientation.w = 1.0
    msg.position_tolerance = [0.02, 0.02, 0.02]
    msg.orientation_tolerance = [0.1, 0.1, 0.1]
    assert goal_region_from_msg(msg, 'tool0').link == 'tool0'
    msg.link_name = 'flange'
    assert goal_region_from_msg(msg, 'tool0').link == 'flange'


def test_the_attack_weighs_with_the_heatmaps_own_parameters(table_scene):
    cfg = HeatmapConfig(samples=20, kappa=0.05, d_safe_m=0.2, gamma_man=2.0, gamma_clr=0.5)
    heatmap = build_heatmap(table_scene, cfg, seed=1)
    assert weight_config(heatmap) == dataclasses.replace(HeatmapConfig(), kappa=0.05,
                                                         d_safe_m=0.2, gamma_man=2.0,
                                                         gamma_clr=0.5)
    heatmap.meta['params'] = {}  # a file that records none was built with the defaults
    assert weight_config(heatmap) == HeatmapConfig()
    from advocc_ros.attack import AttackConfig
    from advocc_ros.attack.region import search_region
    from advocc_ros.model.robot import load_robot
    robot = load_robot(table_scene.robot)
    heatmap.meta['params'] = dataclasses.asdict(cfg)
    region = search_region(heatmap, robot, table_scene.objects,
                           np.array([table_scene.start[n] for n in robot.joint_names]),
                           table_scene.goal, AttackConfig())
    assert region.weight_config.kappa == 0.05 and region.weight_config.gamma_clr == 0.5


def _subcommand(parser, *path):
    for name in path:
        action = next(a for a in parser._actions if hasattr(a, 'choices')
                      and isinstance(a.choices, dict) and name in a.choices)
        parser = action.choices[name]
    return parser


def test_every_command_that_attacks_takes_the_same_task_and_attack_arguments():
    from advocc_ros.attack.types import DEFAULT_METHOD, AttackConfig
    from advocc_ros.cli import build_parser
    root = build_parser()
    expect = {'method': DEFAULT_METHOD, 'policy': AttackConfig().goal_policy,
              'size': AttackConfig().box_size_m, 'seed': 0}
    for path in (('attack',), ('audit',), ('call', 'attack')):
        p = _subcommand(root, *path)
        dests = {a.dest: a for a in p._actions}
        assert {'scene', 'request', 'goal_tol'} <= set(dests), path
        assert {k: dests[k].default for k in expect} == expect, path
        assert '``' not in (p.description or '') and 'lives in' not in (p.description or '')


def test_the_cache_facility_is_bounded_lru_and_keeps_the_first_value():
    import threading

    from advocc_ros.model.cache import BoundedCache
    cache = BoundedCache('test', 2)
    assert cache.get_or_make('a', lambda: 1) == 1 and cache.get_or_make('b', lambda: 2) == 2
    assert cache.get('a') == 1  # 'a' is now the most recently used
    cache.put('c', 3)
    assert 'b' not in cache and 'a' in cache and len(cache) == 2
    assert cache.put('a', 99) == 1  # the first value stored is kept
    built = []

    def make():
        built.append(1)
        return len(built)

    got = []
    threads = [threading.Thread(target=lambda: got.append(cache.get_or_make('d', make)))
               for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(got)) == 1 and got[0] == cache.get('d')  # every thread sees the kept value
    assert len(cache) == 2
    cache.clear()
    assert len(cache) == 0 and cache.get('a') is None


def test_clear_task_caches_forgets_what_a_new_task_computes_again():
    """The cold timings of ``advocc perf attack``: per-task caches go, the others stay."""
    from advocc_ros.attack import goals, policy
    from advocc_ros.kinematics import goal_batch
    from advocc_ros.model import collision
    from advocc_ros.model.cache import BoundedCache, clear_task_caches

    mine, kept = BoundedCache('test task', 2, per_task=True), BoundedCache('test model', 2)
    mine.put('a', 1)
    kept.put('a', 1)
    clear_task_caches()
    assert 'a' not in mine and 'a' in kept
    from advocc_ros.model.cache import task_caches
    for cache in (goals.GOAL_SAMPLES, goal_batch.TASK_GOAL_SAMPLES, policy.WITNESS_BODIES):
        assert cache in task_caches(), cache.name
    assert collision.SHARED_WORLDS not in task_caches()


def test_a_collision_world_is_freed_when_dropped(panda, table_scene):
    """No reference cycle between a world and its per-thread data: a node builds worlds per
    request, and a cycle kept their C++ data until the next garbage collection (+30 MB over
    40 attacks)."""
    import gc
    import weakref

    from advocc_ros.model.collision import CollisionWorld
    gc.disable()
    try:
        world = CollisionWorld(panda, table_scene.shapes)
        q = panda.sample_q(np.random.default_rng(0), 1)[0]
        world.in_collision(q)
        world.scene_distance(q)
        alive = weakref.ref(world)
        del world
        assert alive() is None
    finally:
        gc.enable()


def test_call_attack_waits_long_enough_for_a_first_solvable_attack():
    from advocc_ros.cli import build_parser
    from advocc_ros.commands.call import SOLVABLE_TIMEOUT_S, TIMEOUT_S, attack_timeout_s
    args = build_parser().parse_args(['call', 'attack', '--scene', 'table_pick', '--budget', '3',
                                      '--policy', 'solvable'])
    assert attack_timeout_s(args.timeout, args.policy) == SOLVABLE_TIMEOUT_S >= 120
    assert attack_timeout_s(None, 'paper') == TIMEOUT_S
    assert attack_timeout_s(30.0, 'solvable') == 30.0  # a given --timeout wins


@pytest.mark.processes
def test_a_named_command_loads_only_its_own_module():
    """``advocc attack`` does not import the other commands (ROS, the bench, the heatmap build's
    mesh tools): a warm attack is dominated by imports otherwise. ``advocc --help`` lists all."""
    import subprocess
    import sys
    code = ('import sys; from advocc_ros.cli import build_parser; '
            "build_parser(['-v', 'attack']); "
            "print(sorted(m for m in sys.modules if m.startswith('advocc_ros.commands.')), "
            "'trimesh' in sys.modules, 'rclpy' in sys.modules)")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "['advocc_ros.commands.attack', 'advocc_ros.commands.common'] False False"
    from advocc_ros.cli import COMMANDS, build_parser
    for argv in (None, ['--help'], ['no-such-command']):
        choices = next(a.choices for a in build_parser(argv)._actions if isinstance(
            getattr(a, 'choices', None), dict))
        assert list(choices) == COMMANDS


@pytest.mark.processes
def test_the_message_only_nodes_load_no_compiler():
    """The planner shim and the attacker only convert messages and plan or ask: they start
    without the compiled kernels or scipy (``attack/`` and ``heatmap/`` load a name's module on
    first use), and the attack package still hands out every name it lists."""
    import subprocess
    import sys
    code = ('import sys, advocc_ros.nodes.planner_shim, advocc_ros.nodes.attacker; '
            "print(sorted(m for m in ('advocc_ros.kernels', 'scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == '[]'
    import advocc_ros.attack
    import advocc_ros.heatmap
    for package in (advocc_ros.attack, advocc_ros.heatmap):
        assert all(getattr(package, name) is not None for name in package.__all__)
        with pytest.raises(AttributeError, match='no attribute'):
            getattr(package, 'no_such_name')
