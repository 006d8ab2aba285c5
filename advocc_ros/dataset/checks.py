"""Every exported witness of a build folder asked again, from its files alone: the continuous
certificate (coal's distances on the exported scene, to the exported request's goal) and MPlib's
own collision check (FCL on its model, ``job.mplib_witness_check``).

A hardened problem is hard for a victim only if its witness is a solution in that victim's own
eyes: a corridor MPlib's checker calls closed is none for MPlib. ``advocc dataset check`` runs
this on a folder a user extracted from a published archive, so the claim rests on the files
shipped, not on the build's own record; one MPlib worker serves every problem.
"""

from __future__ import annotations

import json
import pathlib
from typing import Iterator

CHECKS_FILE = 'witness_checks.csv'
CHECKERS = ('coal', 'mplib')
COLUMNS = ('family', 'problem', 'budget', 'goal_form', 'certificate', 'min_clearance_mm',
           'mplib_states', 'mplib_colliding', 'mplib_accepted', 'mplib_error', 'message')
"""``witness_checks.csv``: one row per exported witness. ``certificate`` is ``certified``,
``refused`` or ``unreadable`` (a file of the problem is missing or damaged; ``message`` says why
for both); ``min_clearance_mm`` is the smallest distance the certificate measured; the
``mplib_`` columns are empty when MPlib was not asked, and ``mplib_error`` says why when it
could not answer (its worker died; the next problem starts another). A problem whose
``hardness.json`` cannot be read is one ``unreadable`` row of budget 0."""


def exported(out: pathlib.Path) -> Iterator[tuple[str, str, int, pathlib.Path | str]]:
    """(family, problem number, budget, folder) of every exported attacked problem, in order;
    for a problem whose ``hardness.json`` cannot be read, budget 0 and why instead of a
    folder."""
    for hardness in sorted(out.glob('*/*/hardness.json')):
        family, number = hardness.parent.parent.name, hardness.parent.name
        try:
            attacks = dict(json.loads(hardness.read_text()).get('attacks', {}))
            budgets = sorted(attacks, key=int)
        except (OSError, ValueError, TypeError, AttributeError) as exc:
            yield family, number, 0, f'{hardness}: cannot be read ({exc})'
            continue
        for budget in budgets:
            if attacks[budget].get('exported'):
                yield family, number, int(budget), hardness.parent / attacks[budget]['exported']


def check_problem(folder: pathlib.Path, number: str, victim=None) -> dict:
    """The checks of one exported problem (``sceneNNNN``, ``requestNNNN``, ``trajectoryNNNN``
    in ``folder``): the row of ``COLUMNS`` without its family, problem and budget."""
    from advocc_ros.dataset.job import mplib_witness_check
    from advocc_ros.model.collision import CollisionWorld
    from advocc_ros.planning.witness import certify, object_shape_names
    from advocc_ros.planning.worker import WorkerDied

    try:
        scene, robot, q_init, witness = _load(folder, number)
    except (OSError, ValueError) as exc:  # a file missing or damaged (the loaders say which)
        return _unreadable(str(exc))
    world = CollisionWorld(robot, scene.shapes)
    why, proof = certify(robot, world, scene.goal, witness, q_init,
                         shape_names=object_shape_names(scene.objects))
    row = {'goal_form': 'joint' if scene.goal.is_joint else 'region',
           'certificate': 'certified' if why is None else 'refused', 'message': why or '',
           'min_clearance_mm': '' if proof is None else round(proof.min_clearance_m * 1e3, 4)}
    if victim is not None:
        try:
            check = mplib_witness_check(scene, robot, q_init, witness, victim)
        except WorkerDied as exc:
            return dict(row, mplib_error=str(exc))
        row.update(mplib_states=check['states'], mplib_colliding=check['colliding'],
                   mplib_accepted=check['accepted'])
    return row


def _unreadable(why: str) -> dict:
    """The row of a problem whose files cannot be read."""
    return dict(goal_form='', certificate='unreadable', message=why, min_clearance_mm='')


def _load(folder: pathlib.Path, number: str):
    """The exported scene, its posed robot and start, and the witness, from the files."""
    from advocc_ros.dataset.job import posed
    from advocc_ros.formats.mbm_export import load_trajectory
    from advocc_ros.formats.mbm_scene import load_any_scene
    from advocc_ros.planning.witness import Witness

    scene = load_any_scene(folder / f'scene{number}.yaml', folder / f'request{number}.yaml')
    robot, q_init, _ = posed(scene)
    names, waypoints = load_trajectory(folder / f'trajectory{number}.yaml')
    return scene, robot, q_init, Witness(tuple(names), waypoints, dict(robot.locked_values), {})


def check_folder(out: pathlib.Path, checkers: tuple[str, ...] = CHECKERS) -> Iterator[dict]:
    """The row of every exported witness of the build folder ``out``, one at a time."""
    from advocc_ros.planning.victims import VictimConfig, make_victim

    victim = make_victim('mplib', VictimConfig()) if 'mplib' in checkers else None
    try:
        for family, number, budget, folder in exported(out):
            row = _unreadable(folder) if isinstance(folder, str) else \
                check_problem(folder, number, victim)
            yield dict(family=family, problem=number, budget=budget, **row)
    finally:
        if victim is not None:
            victim.close()


def counts(rows: list[dict]) -> dict:
    """``witness_checks.json``: how many witnesses each checker accepts, in all and per family
    and budget (``mplib_accepted`` None when MPlib was not asked), and the goal forms."""
    def tally(group: list[dict]) -> dict:
        asked = [r for r in group if 'mplib_accepted' in r]
        return {'witnesses': len(group),
                'certified': sum(r['certificate'] == 'certified' for r in group),
                'unreadable': sum(r['certificate'] == 'unreadable' for r in group),
                'mplib_errors': sum(bool(r.get('mplib_error')) for r in group),
                'mplib_accepted': sum(r['mplib_accepted'] for r in asked) if asked else None}

    keys = sorted({(r['family'], r['budget']) for r in rows})
    groups = [dict(family=f, budget=b,
                   **tally([r for r in rows if (r['family'], r['budget']) == (f, b)]))
              for f, b in keys]
    return dict(tally(rows), format='advocc_witness_checks',
                goal_forms=sorted({r['goal_form'] for r in rows} - {''}), groups=groups)


__all__ = ['CHECKERS', 'CHECKS_FILE', 'COLUMNS', 'check_folder', 'check_problem', 'counts',
           'exported']
