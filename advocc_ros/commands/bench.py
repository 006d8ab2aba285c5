"""``advocc bench``: the paper's benchmark through real nodes (also the ``orchestrator`` program).

A profile of ``config/bench.yaml`` (``paper`` or ``quick``) sets the protocol; every setting can
be overridden here. Re-running the same command on the same ``--out`` folder resumes it.
"""

from __future__ import annotations

import argparse

from advocc_ros.commands.common import describe
from advocc_ros.orchestrator.cli import add_bench_args, run


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser('bench', help='run the paper\'s benchmark through the nodes',
                            description=describe(__doc__))
    add_bench_args(parser)
    parser.set_defaults(func=run)
