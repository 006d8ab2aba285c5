"""Arguments shared by commands, with one set of defaults: the task (which scene, our YAML or
MotionBenchMaker files, which request, which goal tolerance) and the attack (method, goal
policy, box size, seed)."""

from __future__ import annotations

import argparse
import re

from advocc_ros.cli import UserError
from advocc_ros.model.goal import GOAL_FORMS
from advocc_ros.model.scene import Scene

GOAL_TOL_HELP = ('tolerances of the goal region: "pos=X[,Y,Z];rot=R[,P,Y]" (half-extents [m] '
                 'and rotation-vector tolerances [rad] in the end-effector frame; one value = '
                 'all axes; default pos=0.02;rot=0.1). With --request they shape the region '
                 'built around the request\'s goal; without, they replace the scene goal\'s')


def describe(doc: str) -> str:
    """A command module's docstring as its ``--help`` shows it: the first paragraph, without the
    ``advocc name``: prefix and the reST markup (for users, not for the code's readers)."""
    text = ' '.join(doc.strip().split('\n\n')[0].split())
    text = re.sub(r'^``advocc [\w -]+``:\s*', '', text).replace('``', '')
    return text[:1].upper() + text[1:]


def add_scene_args(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """Add ``--scene``, ``--request``, ``--goal-form`` and ``--goal-tol`` to ``parser``."""
    parser.add_argument('--scene', required=required,
                        help='scene: our YAML file, a shipped name (table_pick, '
                             'table_under_pick, bookshelf, box, cage) or a MotionBenchMaker '
                             'scene file (MoveIt PlanningScene YAML, sceneNNNN.yaml)')
    parser.add_argument('--request', metavar='FILE',
                        help='MotionBenchMaker request file (requestNNNN.yaml): its start state '
                             'and its goal replace the scene\'s (a joint goal in --goal-form, '
                             'or a pose goal\'s own region)')
    parser.add_argument('--goal-form', choices=GOAL_FORMS,
                        help='how a request\'s joint goal is posed: joint (the configuration '
                             'itself, as MotionBenchMaker, MoveIt and VAMP plan to it; the '
                             'default for a joint goal) or region (the paper\'s tolerance '
                             'region around its end-effector pose, --goal-tol; the default '
                             'for our scenes and pose goals)')
    parser.add_argument('--goal-tol', metavar='TOL', help=GOAL_TOL_HELP)


def add_attack_args(parser: argparse.ArgumentParser, methods=None) -> None:
    """Add ``--method``, ``--policy``, ``--size`` and ``--seed`` to ``parser``, with the
    defaults of ``AttackConfig`` and ``DEFAULT_METHOD`` (``methods``: the choices, default
    every known method)."""
    from advocc_ros.attack.methods import KNOWN_METHODS
    from advocc_ros.attack.types import DEFAULT_METHOD, POLICIES, AttackConfig

    defaults = AttackConfig()
    parser.add_argument('--method', default=DEFAULT_METHOD, choices=methods or KNOWN_METHODS,
                        help='task: coverage of the task\'s goal and approach configurations '
                             '(the one that makes planners fail); ours: the paper\'s heatmap '
                             'coverage; random; pfa, pfa++: planner in the loop (default '
                             '%(default)s)')
    parser.add_argument('--policy', default=defaults.goal_policy, choices=POLICIES,
                        help='goal policy: paper (boxes may block every goal pose), reachable '
                             '(keep a fraction of fixed goal samples valid) or solvable (keep the '
                             'task\'s witness path valid: the task stays certified solvable; '
                             'finds the witness first, one RRTConnect run per task) (default '
                             '%(default)s)')
    parser.add_argument('--size', type=float, default=defaults.box_size_m, metavar='M',
                        help='box edge s [m] (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0,
                        help='attack seed (task, random, pfa, pfa++) (default %(default)s)')


def add_task_option_arg(parser: argparse.ArgumentParser, defaults: tuple[str, ...] = ()
                        ) -> None:
    """Add the repeatable ``--task-option KEY=VALUE`` (``TaskOptions`` of method ``task``);
    ``defaults`` (``KEY=VALUE`` items) come first, so a given option overrides them."""
    parser.add_argument('--task-option', action='append', default=list(defaults),
                        metavar='KEY=VALUE',
                        help='a setting of --method task (advocc_ros.attack.task.TaskOptions; '
                             'YAML value, repeatable), e.g. tube_samples=512 or detours=0'
                             + (f' (default {" ".join(defaults)})' if defaults else ''))


def task_options_from_args(args: argparse.Namespace, method: str):
    """The ``TaskOptions`` of ``--task-option`` (None when none is given); ``UserError`` for a
    malformed item, an unknown option, a bad value, or options given to another method."""
    import yaml

    from advocc_ros.attack.task import task_options

    if not args.task_option:
        return None
    if method != 'task':
        raise UserError(f'--task-option applies to the task method only, not {method!r}')
    mapping = {}
    for item in args.task_option:
        key, sep, text = item.partition('=')
        if not sep or not key.strip():
            raise UserError(f'--task-option {item!r}: expected KEY=VALUE, e.g. detours=0')
        try:
            mapping[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise UserError(f'--task-option {item!r}: the value is not YAML') from None
    try:
        return task_options(mapping)
    except ValueError as exc:
        raise UserError(f'--task-option: {str(exc).removeprefix("task options: ")}') from None


def scene_from_args(args: argparse.Namespace) -> Scene | None:
    """The scene named by ``--scene/--request/--goal-tol``; None if ``--scene`` was optional
    and not given. Errors are ``SceneError`` naming the file and field."""
    from advocc_ros.formats.mbm_scene import load_any_scene

    if args.scene is None:
        if getattr(args, 'request', None) or getattr(args, 'goal_tol', None) \
                or getattr(args, 'goal_form', None):
            raise ValueError('--request, --goal-form and --goal-tol need a --scene')
        return None
    return load_any_scene(args.scene, getattr(args, 'request', None),
                          getattr(args, 'goal_tol', None), getattr(args, 'goal_form', None))


def add_bag_arg(parser: argparse.ArgumentParser) -> None:
    """Add ``--bag FILE.mcap`` (record the attack as a ROS 2 bag)."""
    parser.add_argument('--bag', metavar='FILE.mcap',
                        help='also record the scene, goal region, boxes and heatmap as a ROS 2 '
                             'bag (rosbag2\'s MCAP storage)')


def check_bag_arg(args: argparse.Namespace) -> None:
    """Refuse a ``--bag`` name rosbag2 would not read as MCAP, before any work is done."""
    if getattr(args, 'bag', None) and not args.bag.endswith('.mcap'):
        raise ValueError(f'--bag: {args.bag} must end in .mcap (rosbag2\'s MCAP storage)')


def refuse_invalid_task(scene, what: str) -> None:
    """``UserError`` with the reason when ``scene``'s task (its objects and boxes, start, goal)
    is refused by ``model.task_check``: a planner failing it, or an attack on it, would measure
    nothing. Commands call it before any heatmap, planner or trial."""
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.task_check import check_task

    robot = load_robot(scene.robot)
    fault = check_task(robot, scene.objects, start_configuration(scene, robot), scene.goal)
    if fault is not None:
        raise UserError(f'{what}: the task is refused: {fault.message}')


def add_victim_args(parser: argparse.ArgumentParser) -> None:
    """Add the victims' goal options (``--goal-list``, ``--goal-configs``)."""
    from advocc_ros.planning.victims import VictimConfig
    parser.add_argument('--goal-list', action='store_true',
                        help='our OMPL planners plan to the same K goal configurations the '
                             'outside victims get (sampled before the clock starts) instead '
                             'of sampling the goal region inside their budget')
    parser.add_argument('--goal-configs', type=int, default=VictimConfig().goal_configs,
                        metavar='K', help='goal configurations given to victims that take '
                                          'only configurations (default %(default)s)')


def victim_config_from_args(args: argparse.Namespace, planning=None):
    """The ``VictimConfig`` of ``--goal-list``/``--goal-configs`` (and a ``PlanningConfig``)."""
    from advocc_ros.planning.types import PlanningConfig
    from advocc_ros.planning.victims import VictimConfig
    if args.goal_configs < 1:
        raise ValueError(f'--goal-configs must be >= 1, got {args.goal_configs}')
    return VictimConfig(planning=planning or PlanningConfig(), goal_configs=args.goal_configs,
                        ompl_goal_list=args.goal_list)
