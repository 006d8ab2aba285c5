"""``advocc robot srdf``: an SRDF with the disabled collision pairs MoveIt's Setup Assistant finds.

For arms whose shipped SRDF has no (or too few) ``<disable_collisions>``: adjacent links, pairs in
collision in the default state, always or never in collision over random states
(``advocc_ros.formats.srdf``). With ``--srdf``, that file's groups, states and pairs are kept and
the new pairs added.
"""

from __future__ import annotations

import argparse
import json
import xml.etree.ElementTree as ET
from collections import Counter

from advocc_ros.cli import UserError
from advocc_ros.commands.common import describe


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('robot', help='robot description tools (SRDF generation)')
    rsub = parser.add_subparsers(dest='robot_command', required=True)
    srdf = rsub.add_parser('srdf', help='write an SRDF with the disabled collision pairs of '
                                        'MoveIt\'s Setup Assistant',
                           description=describe(__doc__))
    srdf.add_argument('--urdf', required=True,
                      help='URDF file or example-robot-data://<robot>/urdf/<file>.urdf')
    srdf.add_argument('--srdf', help='an SRDF to extend (its groups and states are kept)')
    srdf.add_argument('--group', default='arm', help='name of the group of --group-joints')
    srdf.add_argument('--group-joints', nargs='+', default=(),
                      help='joints of a planning group to write (default: none)')
    srdf.add_argument('--samples', type=int, default=10000,
                      help='random states for the always/never tests (default %(default)s, as '
                           'the Setup Assistant)')
    srdf.add_argument('--always-fraction', type=float, default=0.95,
                      help='a pair in collision in at least this fraction of the states is '
                           'disabled as Always (default %(default)s)')
    srdf.add_argument('--seed', type=int, default=0)
    srdf.add_argument('--threads', type=int, default=1,
                      help='threads of computeCollisionsInParallel (default %(default)s)')
    srdf.add_argument('--out', required=True, help='SRDF file to write')
    srdf.add_argument('--json', action='store_true', help='print the pairs as JSON')
    srdf.set_defaults(func=_srdf)


def _srdf(args: argparse.Namespace) -> int:
    from advocc_ros.fileio import atomic_write_text
    from advocc_ros.model.robot import example_robot_data_share, resolve_path
    from advocc_ros.formats.srdf import disabled_collision_pairs, srdf_text

    if not 1 <= args.samples <= 10 ** 7:
        raise UserError('--samples must be in 1..10^7')
    if not 0.0 < args.always_fraction <= 1.0:
        raise UserError('--always-fraction must be in (0, 1]')
    if args.threads < 1:
        raise UserError('--threads must be >= 1')
    urdf = resolve_path(args.urdf)
    if not urdf.is_file():
        raise UserError(f'URDF not found: {urdf}')
    try:
        urdf_root = ET.parse(urdf).getroot()
        base = ET.parse(resolve_path(args.srdf)).getroot() if args.srdf else None
    except ET.ParseError as exc:
        raise UserError(f'not valid XML: {exc}') from None
    joints = {j.get('name') for j in urdf_root.iter('joint')}
    unknown = [j for j in args.group_joints if j not in joints]
    if unknown:
        raise UserError(f'--group-joints: {unknown} are not joints of {urdf}')
    try:
        result = disabled_collision_pairs(urdf, [str(example_robot_data_share())], args.samples,
                                          args.seed, args.always_fraction, args.threads)
    except (RuntimeError, ValueError) as exc:
        raise UserError(f'{urdf}: pinocchio could not load it ({exc})') from None
    atomic_write_text(args.out, srdf_text(urdf_root.get('name', 'robot'), result.disabled,
                                          args.group, args.group_joints, base))
    counts = Counter(d.reason for d in result.disabled)
    if args.json:
        print(json.dumps({'out': args.out, 'links': list(result.links),
                          'samples': result.samples, 'counts': dict(counts),
                          'disabled': [[d.link1, d.link2, d.reason] for d in result.disabled],
                          'enabled': [list(p) for p in result.enabled]}, indent=1))
    else:
        print(f'{args.out}: {len(result.disabled)} disabled pairs of {len(result.links)} links '
              f'({", ".join(f"{r} {n}" for r, n in counts.items())}); '
              f'{len(result.enabled)} pairs stay checked')
    return 0
