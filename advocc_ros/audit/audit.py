"""The audit: how few boxes make a planner fail one task, and where do they go (docs/design.md).

It answers the honest question twice: how few boxes make the pick impossible (every goal
configuration blocked, from a paper-policy attack), and how few make each planner fail while
the task stays certified solvable (a witness path stays valid with the boxes; the ``solvable``
goal policy keeps it so by construction). A planner failing an impossible task shows nothing.

Greedy picks are nested (the first m boxes of a budget-K attack are the budget-m attack), so one
attack at the largest budget K and an evaluation of its prefixes m = 0, 1, 2, ... give, per
planner, the PSR curve over the budget and the minimal budget reaching each PSR threshold (the
paper's Table II for one task).

By default every planner is evaluated at every prefix and the sweep stops after the first m at
which every planner is at PSR 0, or at the last box the attack placed. With a target PSR, a planner
is evaluated until its PSR is at most the target (later prefixes: None) and the sweep stops when
every planner got there; with a grid of prefixes only those m are evaluated (and get a verdict), so
an answer m means "between the previous evaluated prefix + 1 and m". Trial k uses seed ``seed + k``
at every m, so the prefixes are compared on the same random numbers. ``advocc_ros.audit.report``
renders the result. No ROS.
"""

from __future__ import annotations

import dataclasses
import logging
import numbers
import time
from typing import Any, Callable

from advocc_ros.attack.types import DEFAULT_METHOD, AttackConfig
from advocc_ros.evaluation.budgets import THRESHOLDS, minimal_budgets

log = logging.getLogger(__name__)

ANSWER_THRESHOLD = 0.2
"""A planner "fails" the task when its PSR is at most this (the answer's headline, unless the
audit has a ``target_psr``: then that)."""
AUDIT_FORMAT = 'advocc_audit'
AUDIT_VERSION = 4
"""4: the keys of 3; every prefix m is the first m boxes (``boxes``) of the one attack at the
largest budget, under every goal policy. Version 4 files written while a ``solvable`` prefix
could be an attack of its own may hold, in an entry of ``budgets``, that attack's ``attack``,
``boxes`` and ``witness`` (``report.prefix_boxes`` reads them).
3: ``budgets`` holds the evaluated prefixes only (``--prefixes``), a planner's row there is None
once it reached ``target_psr``, ``psr`` curves are None where not evaluated. Versions 2 (every
prefix, every planner) and 3 read the same way."""


@dataclasses.dataclass(frozen=True)
class AuditConfig:
    """What one audit runs: the attack, the victims and the trials."""

    planners: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1')
    """Victims evaluated at every prefix: OMPL planner ids or outside victims (``mplib``)."""
    max_budget: int = 5
    """K: boxes of the one attack whose prefixes are evaluated."""
    trials: int = 10
    """Plan requests per planner and prefix."""
    time_budget_s: float = 5.0
    """Wall-clock budget of one plan request [s] (the paper: 5)."""
    method: str = DEFAULT_METHOD
    """Attack method (``advocc_ros.attack.methods.REGISTRY``); greedy ones give nested picks."""
    policy: str = AttackConfig.goal_policy
    """Goal policy of the evaluated attack (``advocc_ros.attack.policy``): ``paper``,
    ``reachable`` or ``solvable``; the goal-blocked answer always comes from a paper one."""
    seed: int = 0
    """Attack seed; trial k of every prefix uses seed ``seed + k``."""
    workers: int = 2
    """Planner processes serving the trials in parallel (keep <= free cores: PT is wall time)."""
    target_psr: float | None = None
    """PSR (fraction in [0, 1]) at which a planner counts as failed: it is not evaluated at later
    prefixes and the sweep stops once every planner got there. None: every planner at every
    prefix until all are at PSR 0 at the same m (the full curves)."""
    prefixes: tuple[int, ...] | None = None
    """The m evaluated (0, the unattacked control, always added; sorted); None: every m up to
    the boxes placed. Those beyond the boxes the attack placed are dropped with a warning."""
    task_options: Any = None
    """``advocc_ros.attack.task.TaskOptions`` of a ``task`` attack (None: its defaults)."""

    def __post_init__(self):
        if not self.planners:
            raise ValueError('audit: no planners')
        if self.max_budget < 1:
            raise ValueError(f'audit: max budget must be >= 1, got {self.max_budget}')
        if self.trials < 1:
            raise ValueError(f'audit: trials must be >= 1, got {self.trials}')
        if not self.time_budget_s > 0:
            raise ValueError(f'audit: time budget must be > 0 s, got {self.time_budget_s}')
        if self.workers < 1:
            raise ValueError(f'audit: workers must be >= 1, got {self.workers}')
        if self.target_psr is not None and not 0.0 <= self.target_psr <= 1.0:  # NaN too
            raise ValueError(f'audit: target PSR must be a fraction in [0, 1], '
                             f'got {self.target_psr}')
        if self.prefixes is not None:
            object.__setattr__(self, 'prefixes', self._grid(self.prefixes))

    def _grid(self, prefixes) -> tuple[int, ...]:
        """``prefixes`` checked (integers in 0..max_budget), sorted, with 0."""
        bad = [m for m in prefixes if isinstance(m, bool) or not isinstance(m, numbers.Integral)
               or not 0 <= m <= self.max_budget]
        if bad:
            raise ValueError(f'audit: prefixes must be integers in 0..{self.max_budget} (the '
                             f'max budget), got {bad}')
        return tuple(sorted({0, *(int(m) for m in prefixes)}))

    def thresholds(self) -> tuple[float, ...]:
        """The PSR thresholds of the minimal budgets: the paper's, and the target if it is not
        one of them (descending)."""
        if self.target_psr is None or self.target_psr in THRESHOLDS:
            return THRESHOLDS
        return tuple(sorted((*THRESHOLDS, self.target_psr), reverse=True))


def _row(result: dict) -> dict:
    keys = ('psr', 'successes', 'trials', 'internal_errors', 'pt', 'smr', 'cmr', 'jds',
            'failures', 'first_solution_median_s', 'first_solution_p90_s', 'psr_at')
    return {k: result[k] for k in keys}


def run_audit(scene, heatmap, cfg: AuditConfig = AuditConfig(),
              progress: Callable[[int, str, dict], None] | None = None,
              attack_cfg=None, planning_config=None) -> dict[str, Any]:
    """One attack at budget ``cfg.max_budget`` on ``scene``'s task, then its prefixes m = 0, 1,
    ... (or ``cfg.prefixes``) evaluated per planner (see the module docstring); returns the
    JSON-able audit.

    Every evaluated prefix gets a ``solvable`` verdict (``certified`` / ``goal blocked`` /
    ``unknown``, ``advocc_ros.attack.solvable``; prefixes off the grid get none, and cost no
    certificate work); ``min_budget_solvable`` counts only certified prefixes; both minimal
    budgets include ``cfg.target_psr`` as a threshold.
    ``impossible`` answers how few boxes block the goal: the prefixes of a paper-policy attack
    (this one when the policy is paper) up to the first one whose verdict is ``goal blocked``.
    ``progress(m, planner, row)`` is called after each evaluation. Raises ``ValueError`` when
    the task is refused (``model.task_check``: the reason, before any planner runs), an attack
    cannot run (its status and message) or the scene has no start or goal.

    Planners run in two places only: the task's witness, found once (one RRTConnect run on the
    unattacked scene, cached; ``witness_search_s``), and the evaluated victims. The attacks
    themselves query none.
    """
    from advocc_ros.attack import AttackConfig
    from advocc_ros.evaluation.perf import machine

    _check_request(scene, cfg)
    attack_cfg = attack_cfg or AttackConfig()
    t_start = time.perf_counter()
    task, search = _task_under_audit(scene, attack_cfg.victim_margin_m)
    result = _attack(task, heatmap, cfg, cfg.policy, attack_cfg)
    log.info('audit %s: %d boxes (%s), evaluating prefixes', scene.name,
             len(result.obstacles), result.status.value)
    budgets, psr, stop_reason = _sweep(task, result, cfg, progress, planning_config)
    paper = result
    if cfg.policy != 'paper':
        paper = _attack(task, heatmap, cfg, 'paper', attack_cfg)
    known = {b['m']: b['solvability'] for b in budgets} if paper is result else {}
    return {
        **_header(scene, heatmap, cfg, result),
        'witness': None if result.witness is None else result.witness.to_data(),
        'witness_search_s': round(search.search_s, 3),
        'boxes': _boxes_json(result),
        'budgets': budgets,
        'psr': psr,
        **_minimal_budgets(cfg, budgets, psr),
        'stopped': stop_reason,
        'impossible': _impossible(task, paper, same_attack=paper is result, known=known),
        'wall_s': round(time.perf_counter() - t_start, 2),
        'machine': machine(),
    }


def _check_request(scene, cfg: AuditConfig) -> None:
    """Refuse, before any work, a scene without a start or a goal and an unknown method."""
    from advocc_ros.attack.methods import REGISTRY

    if scene.goal is None or scene.start is None:
        raise ValueError(f'scene {scene.name!r} needs a start and a goal to be audited')
    if cfg.method not in REGISTRY:
        raise ValueError(f'unknown attack method {cfg.method!r}; known: {list(REGISTRY)}')


def _task_under_audit(scene, clearance_m: float):
    """``scene``'s task, refused when invalid (``model.task_check``), with its witnesses, and
    the witness search that found them (on the unattacked scene, ``clearance_m`` clear of it
    when it can be, cached)."""
    from advocc_ros.attack.edges import task_witness
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.task_check import require_valid_task

    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    require_valid_task(robot, scene.objects, q_init, scene.goal)
    search = task_witness(robot, scene.objects, q_init, scene.goal, clearance_m)
    return _Task(scene, robot, q_init, search.witnesses), search


def _header(scene, heatmap, cfg: AuditConfig, result) -> dict:
    """The audit's first keys: format, scene, method, settings (with the heatmap's summary) and
    the attack at the largest budget."""
    from advocc_ros.attack.methods import REGISTRY

    return {
        'format': AUDIT_FORMAT, 'version': AUDIT_VERSION,
        'scene': scene.name, 'scene_hash': scene.objects_hash(),
        'method': cfg.method, 'method_label': REGISTRY[cfg.method].label, 'policy': cfg.policy,
        'max_budget': cfg.max_budget,
        'settings': dict(dataclasses.asdict(cfg), planners=list(cfg.planners),
                         box_size_m=result.box_size_m,
                         heatmap={k: heatmap.meta.get(k) for k in
                                  ('valid_samples', 'scene_name', 'build_s')}),
        'attack': _attack_json(result),
    }


def _minimal_budgets(cfg: AuditConfig, budgets: list[dict],
                     psr: dict[str, list[float | None]]) -> dict:
    """``min_budget`` over every evaluated prefix and ``min_budget_solvable`` over the certified
    ones only, both at ``cfg.thresholds()``."""
    verdicts = {b['m']: b['solvable'] for b in budgets}
    certified = {p: [v if verdicts.get(m) == 'certified' else None for m, v in enumerate(curve)]
                 for p, curve in psr.items()}
    return {'min_budget': minimal_budgets(psr, cfg.thresholds()),
            'min_budget_solvable': minimal_budgets(certified, cfg.thresholds())}


@dataclasses.dataclass(frozen=True)
class _Task:
    """The task under audit: its scene, robot, start and candidate witnesses (empty: the
    search found none)."""

    scene: Any
    robot: Any
    q_init: Any
    witness: Any = ()

    def solvability(self, attack, m: int) -> dict:
        """The verdict on the task with ``attack``'s first m boxes added, judged with the
        task's witness, as JSON."""
        from advocc_ros.attack.solvable import assess

        return assess(self.robot, self.scene.objects, attack.obstacles[:m], self.scene.goal,
                      attack.witness, self.q_init).to_json()


def _attack(task: _Task, heatmap, cfg: AuditConfig, policy: str, attack_cfg):
    """The audit's attack at ``cfg.max_budget`` boxes under goal policy ``policy``, with the
    task's witnesses (found once by ``run_audit``)."""
    from advocc_ros.attack import AttackStatus, attack
    from advocc_ros.attack.edges import no_witness_message

    result = attack(heatmap, task.robot, task.scene.objects, task.q_init, task.scene.goal,
                    cfg.max_budget, cfg.method, attack_cfg, seed=cfg.seed,
                    goal_policy=policy, witness=task.witness, method_options=cfg.task_options)
    if not result.status.ok:
        why = (no_witness_message(task.scene.goal.form)
               if result.status == AttackStatus.NO_WITNESS
               else result.message)
        raise ValueError(f'attack {cfg.method} (goal policy {policy}) failed: '
                         f'{result.status.value}: {why}')
    return result


def _sweep(task: _Task, attack, cfg: AuditConfig, progress, planning_config
           ) -> tuple[list[dict], dict[str, list[float | None]], str]:
    """The prefixes (every m up to the boxes placed, or ``cfg.prefixes``): each one's verdict
    and the rows of the planners still due (see the module docstring), until the stop rule
    holds; returns the evaluated prefixes, the PSR curves by m (None: not evaluated) and why it
    stopped."""
    from advocc_ros.attack.goals import goal_samples
    from advocc_ros.evaluation.runner import evaluate_planner

    samples = goal_samples(task.robot, task.scene.objects, task.scene.goal)
    budgets, reached = [], {}
    placed = len(attack.obstacles)
    for m in _evaluated_prefixes(cfg, placed):
        entry = _prefix_entry(task, attack, samples, m)
        attacked = task.scene.with_objects(attack.obstacles[:m])
        for planner in cfg.planners:
            if planner in reached:
                entry['planners'][planner] = None  # already at the target PSR
                continue
            row = _row(evaluate_planner(attacked, planner, cfg.trials, cfg.time_budget_s,
                                        seed=cfg.seed, workers=cfg.workers,
                                        planning_config=planning_config))
            entry['planners'][planner] = row
            if cfg.target_psr is not None and _at_most(row['psr'], cfg.target_psr):
                reached[planner] = m
            if progress:
                progress(m, planner, row)
        budgets.append(entry)
        stop = _stop_reason(cfg, entry, reached)
        if stop:
            return budgets, psr_curves(budgets, cfg.planners), stop
    which = 'every prefix' if cfg.prefixes is None else 'every prefix in the grid'
    return (budgets, psr_curves(budgets, cfg.planners),
            f'evaluated {which} up to the {placed} boxes placed')


def _evaluated_prefixes(cfg: AuditConfig, placed: int) -> list[int]:
    """The m to evaluate: ``cfg.prefixes`` (or every m) up to the ``placed`` boxes; warns about
    the dropped ones."""
    if cfg.prefixes is None:
        return list(range(placed + 1))
    dropped = [m for m in cfg.prefixes if m > placed]
    if dropped:
        log.warning('audit: prefixes %s dropped: the attack placed %d boxes', dropped, placed)
    return [m for m in cfg.prefixes if m <= placed]


def _prefix_entry(task: _Task, attack, samples, m: int) -> dict:
    """Prefix m (``attack``'s first m boxes) without planner rows: its verdict and the goal
    poses left valid."""
    solvability = task.solvability(attack, m)
    return {'m': m, 'goal_valid_fraction':
            samples.valid_fraction(attack.centers_m[:m], attack.box_size_m),
            'solvable': solvability['verdict'], 'solvability': solvability, 'planners': {}}


def _at_most(psr: float | None, threshold: float) -> bool:
    """PSR <= threshold, with ``minimal_budgets``' tolerance; None (not measured) is not."""
    return psr is not None and psr <= threshold + 1e-9


def _stop_reason(cfg: AuditConfig, entry: dict, reached: dict[str, int]) -> str | None:
    """Why the sweep stops after ``entry``, or None to go on."""
    if cfg.target_psr is None:
        if all(entry['planners'][p]['psr'] == 0 for p in cfg.planners):
            return f'every planner at PSR 0 % with m = {entry["m"]}'
        return None
    if len(reached) < len(cfg.planners):
        return None
    firsts = ', '.join(f'{p} m = {reached[p]}' for p in cfg.planners)
    return f'every planner at PSR <= {100 * cfg.target_psr:g} % ({firsts})'


def psr_curves(budgets: list[dict], planners) -> dict[str, list[float | None]]:
    """Per planner, its PSR by m (index m) up to the last evaluated prefix; None where the
    planner was not evaluated (skipped prefix, or already at the target)."""
    curves = {p: [None] * (budgets[-1]['m'] + 1) for p in planners}
    for b in budgets:
        for p, row in b['planners'].items():
            curves[p][b['m']] = None if row is None else row['psr']
    return curves


def _impossible(task: _Task, result, same_attack: bool, known: dict[int, dict]) -> dict:
    """The fewest of a paper-policy attack's boxes that block the goal: its prefixes' verdicts
    up to the first ``goal blocked`` (``known``: verdicts already computed, by m)."""
    prefixes = []
    for m in range(1, len(result.obstacles) + 1):
        solvability = known.get(m) or task.solvability(result, m)
        prefixes.append({'m': m, 'solvable': solvability['verdict'],
                         'solvability': solvability})
        if solvability['verdict'] == 'goal blocked':
            break
    blocked = [p['m'] for p in prefixes if p['solvable'] == 'goal blocked']
    return {'policy': 'paper', 'same_attack': same_attack,
            'attack': _attack_json(result),
            'boxes': [] if same_attack else _boxes_json(result),
            'prefixes': prefixes, 'goal_blocked_m': blocked[0] if blocked else None}


def _attack_json(result) -> dict:
    return {'status': result.status.value, 'message': result.message,
            'compute_ms': round(result.compute_s * 1e3, 3),
            'total_mass': float(result.total_mass),
            'goal_valid_fraction': result.goal_valid_fraction, 'stats': result.stats}


def _boxes_json(result) -> list[dict]:
    import numpy as np

    return [{'pick': i + 1, 'id': obj.id, 'center_m': [round(float(v), 4) for v in np.asarray(c)],
             'size_m': result.box_size_m, 'mass': float(mass)}
            for i, (obj, c, mass) in enumerate(
                zip(result.obstacles, result.centers_m, result.masses))]
