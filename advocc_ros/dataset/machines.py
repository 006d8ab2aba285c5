"""Which machines made a data set's records, and whether their time-bound figures pool.

A victim's budget is wall time, so a PSR measured at ``--time 5`` depends on how much planning
five seconds buy: the CPU model does not say it (two machines named AMD EPYC ran the same
attack 2.5x apart). Each problem probes its machine before its work
(``evaluation.provenance.speed``, validity checks per second); the summary judges each machine
(the Ray node a record ran on) by the median of its records, and a run warns as it starts when
its machine is far from the folder's.
"""

from __future__ import annotations

import logging
import statistics

from advocc_ros.evaluation import provenance

log = logging.getLogger(__name__)


RUN_PROBES = 5
"""A run's driver probes its machine this many times and keeps the median: one probe drifts
up to 1.63x within half a minute, medians of five consecutive ones 1.39x
(docs/results/machine_speed), below the ``provenance.SPEED_SPREAD`` its warning is set at."""


def probe(probes: int = 1) -> float | None:
    """The median of ``probes`` ``provenance.speed`` probes on the CPUs this process holds
    (None if it cannot be measured: the record is still made)."""
    try:
        return statistics.median(provenance.speed() for _ in range(probes))
    except Exception:  # a record without a speed beats no record
        log.exception('the speed probe failed')
        return None


def built_speeds(found: list[dict]) -> list[tuple[str | None, float | None]]:
    """(machine, speed) of each built record: the Ray node it ran on (one machine for one run;
    host names repeat across virtual machines: every sandbox here is ``vm``), else its host;
    and its ``speed_checks_per_s`` (None: unknown)."""
    made = [r.get('provenance') or {} for r in found if r['outcome'] == 'built']
    return [(m.get('node') or m.get('host'), m.get('speed_checks_per_s')) for m in made]


def speeds(found: list[tuple[str | None, float | None]]) -> dict:
    """The summary's ``speed_of_built_problems``: how many built records name their machine's
    speed, its range over them, each machine's median, and whether the machines pool (fastest
    median over slowest at most ``provenance.SPEED_SPREAD``; one machine's probes drift, so it
    is judged by its median; None when no record names a speed)."""
    known = sorted(v for _, v in found if v)
    groups: dict[str, list[float]] = {}
    for where, value in found:
        if value:
            groups.setdefault(str(where), []).append(value)
    machines = {m: statistics.median(v) for m, v in sorted(groups.items())}
    spread = provenance.speed_spread(list(machines.values()))
    pooled = spread is None or spread <= provenance.SPEED_SPREAD
    return {'known': len(known), 'unknown': len(found) - len(known),
            'min': known[0] if known else None,
            'median': statistics.median(known) if known else None,
            'max': known[-1] if known else None, 'machines': machines, 'spread': spread,
            'pooled': pooled if machines else None}


def speed_note(found: list[dict], here: float | None, time_s: float) -> str | None:
    """A warning when this machine's speed and the median of the built records ``found`` (a
    folder's outcome records) differ by more than ``provenance.SPEED_SPREAD``: their PSRs at a
    budget of ``time_s`` seconds and this run's may not pool (the summary judges the machines'
    medians once the records are in). None when they are close or a speed is unknown."""
    known = [v for _, v in built_speeds(found) if v]
    if not here or not known:
        return None
    median = statistics.median(known)
    ratio = max(here, median) / min(here, median)
    if ratio <= provenance.SPEED_SPREAD:
        return None
    return (f'warning: this machine does {here:,.0f} validity checks/s, the {len(known)} built '
            f'record(s) of the folder a median {median:,.0f}/s: {ratio:.2f}x '
            f'{"slower" if here < median else "faster"}, so a {time_s:g} s budget buys that '
            f'much {"less" if here < median else "more"} planning here, and the PSRs this run '
            'measures may not pool with theirs (the summary judges each machine by its median)')


__all__ = ['RUN_PROBES', 'built_speeds', 'probe', 'speed_note', 'speeds']
