"""``advocc``: the command line. Each command group lives in ``advocc_ros.commands.<name>``.

A command module provides ``register(subparsers)``, which adds its parser(s) and sets
``func(args) -> int`` as the handler. Errors the user can fix (bad files, bad values) are
printed as one line on stderr with exit code 2; nothing prints a traceback for them.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

COMMANDS = ['heatmap', 'perf', 'demo', 'audit', 'evaluate', 'attack', 'export', 'call', 'scenes',
            'bench', 'robot', 'view', 'dataset']


class UserError(Exception):
    """An error caused by the user's input; shown without a traceback."""


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or only of the command ``argv`` names.

    Command modules import what their handlers need (compiled kernels, trimesh, ROS); loading only
    the named one saves a warm ``advocc attack`` about 0.4 s.
    """
    parser = argparse.ArgumentParser(
        prog='advocc', description='Adversarial boxes for robot-arm motion planners: how few '
        'boxes make a planner fail a pick, and where they go.', epilog='Start with: advocc '
        'audit --scene table_pick --policy solvable --out out/audit (advocc COMMAND --help for '
        'each command; docs/usage.md walks through them).')
    parser.add_argument('-v', '--verbose', action='store_true', help='debug logging')
    sub = parser.add_subparsers(dest='command', required=True)
    named = [word for word in (argv or []) if not word.startswith('-')][:1]
    for name in named if named and named[0] in COMMANDS else COMMANDS:
        importlib.import_module(f'advocc_ros.commands.{name}').register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format='%(levelname)s %(name)s: %(message)s')
    try:
        return int(args.func(args) or 0)
    except (UserError, ValueError, OSError) as exc:
        print(f'advocc {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'advocc {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    # ``python -m advocc_ros.cli``: run the package module's main, whose UserError is the class
    # the commands raise (this __main__ copy defines another one, which would not catch it).
    from advocc_ros import cli
    sys.exit(cli.main())
