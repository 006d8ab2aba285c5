"""The audit: how few boxes make a planner fail one task, and where do they go (docs/design.md).

It answers the honest question twice: how few boxes make the pick impossible (every goal
configuration blocked, from a paper-policy attack), and how few make each planner fail while
the task stays certified solvable (a witness path stays valid with the boxes; the ``solvable``
goal policy keeps it so by construction). A planner failing an impossible task shows nothing.

Greedy picks are nested (the first m boxes of a budget-K attack are the budget-m attack), so one
attack at the largest budget K and an evaluation of its prefixes m = 0, 1, 2, ... give, per
planner, the PSR curve over the budget and the minimal budget reaching each PSR threshold (the
paper's Table II for one task). The sweep stops after the first m at which every planner is at
PSR 0, or at the last box the attack placed. Trial k uses seed ``seed + k`` at every m, so the
prefixes are compared on the same random numbers. ``audit_report`` renders the result. No ROS.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any, Callable

from advocc_ros.attack.types import DEFAULT_METHOD, AttackConfig
from advocc_ros.evaluation.budgets import minimal_budgets

log = logging.getLogger(__name__)

ANSWER_THRESHOLD = 0.2
"""A planner "fails" the task when its PSR is at most this (the answer's headline)."""
AUDIT_FORMAT = 'advocc_audit'
AUDIT_VERSION = 2


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
    """Goal policy of the evaluated attack (``advocc_ros.attack.goals``): ``paper``,
    ``reachable`` or ``solvable``; the goal-blocked answer always comes from a paper one."""
    seed: int = 0
    """Attack seed; trial k of every prefix uses seed ``seed + k``."""
    workers: int = 2
    """Planner processes serving the trials in parallel (keep <= free cores: PT is wall time)."""

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


def _row(result: dict) -> dict:
    keys = ('psr', 'successes', 'trials', 'internal_errors', 'pt', 'smr', 'cmr', 'jds',
            'failures', 'first_solution_median_s', 'first_solution_p90_s', 'psr_at')
    return {k: result[k] for k in keys}


def run_audit(scene, heatmap, cfg: AuditConfig = AuditConfig(),
              progress: Callable[[int, str, dict], None] | None = None,
              attack_cfg=None, planning_config=None) -> dict[str, Any]:
    """One attack at budget ``cfg.max_budget`` on ``scene``'s task, then every prefix m = 0, 1,
    ... evaluated per planner (see the module docstring); returns the JSON-able audit.

    Every prefix gets a ``solvable`` verdict (``certified`` / ``goal blocked`` / ``unknown``,
    ``advocc_ros.attack.solvable``); ``min_budget_solvable`` counts only certified prefixes.
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
    from advocc_ros.attack.edges import task_witness
    from advocc_ros.attack.methods import REGISTRY
    from advocc_ros.model.task_check import require_valid_task
    from advocc_ros.evaluation.perf import machine
    from advocc_ros.model.robot import load_robot
    from advocc_ros.kinematics.ik import start_configuration

    if scene.goal is None or scene.start is None:
        raise ValueError(f'scene {scene.name!r} needs a start and a goal to be audited')
    if cfg.method not in REGISTRY:
        raise ValueError(f'unknown attack method {cfg.method!r}; known: {list(REGISTRY)}')
    attack_cfg = attack_cfg or AttackConfig()
    t_start = time.perf_counter()
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    require_valid_task(robot, scene.objects, q_init, scene.goal)
    search = task_witness(robot, scene.objects, q_init, scene.goal)
    task = _Task(scene, robot, q_init, search.witness)
    result = _attack(task, heatmap, cfg, cfg.policy, attack_cfg)
    log.info('audit %s: %d boxes (%s), evaluating prefixes', scene.name,
             len(result.obstacles), result.status.value)
    budgets, psr, stop_reason = _sweep(task, result, cfg, progress, planning_config)
    paper = result
    if cfg.policy != 'paper':
        paper = _attack(task, heatmap, cfg, 'paper', attack_cfg)
    known = {b['m']: b['solvability'] for b in budgets} if paper is result else {}
    certified = {p: [v if b['solvable'] == 'certified' else None
                     for v, b in zip(curve, budgets)] for p, curve in psr.items()}
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
        'witness': None if result.witness is None else result.witness.to_data(),
        'witness_search_s': round(search.search_s, 3),
        'boxes': _boxes_json(result),
        'budgets': budgets,
        'psr': psr,
        'min_budget': minimal_budgets(psr),
        'min_budget_solvable': minimal_budgets(certified),
        'stopped': stop_reason,
        'impossible': _impossible(task, paper, same_attack=paper is result, known=known),
        'wall_s': round(time.perf_counter() - t_start, 2),
        'machine': machine(),
    }


@dataclasses.dataclass(frozen=True)
class _Task:
    """The task under audit: its scene, robot, start and witness (None: the search found
    none)."""

    scene: Any
    robot: Any
    q_init: Any
    witness: Any = None

    def solvability(self, boxes: tuple) -> dict:
        """The verdict on the task with ``boxes`` added, as JSON."""
        from advocc_ros.attack.solvable import assess

        return assess(self.robot, self.scene.objects, tuple(boxes), self.scene.goal,
                      self.witness, self.q_init).to_json()


def _attack(task: _Task, heatmap, cfg: AuditConfig, policy: str, attack_cfg):
    """The audit's attack at budget ``cfg.max_budget`` under goal policy ``policy``, with the
    task's witness (found once by ``run_audit``)."""
    from advocc_ros.attack import AttackStatus, attack
    from advocc_ros.attack.edges import no_witness_message

    result = attack(heatmap, task.robot, task.scene.objects, task.q_init, task.scene.goal,
                    cfg.max_budget, cfg.method, attack_cfg, seed=cfg.seed, goal_policy=policy,
                    witness=task.witness)
    if not result.status.ok:
        why = (no_witness_message() if result.status == AttackStatus.NO_WITNESS
               else result.message)
        raise ValueError(f'attack {cfg.method} (goal policy {policy}) failed: '
                         f'{result.status.value}: {why}')
    return result


def _sweep(task: _Task, result, cfg: AuditConfig, progress, planning_config
           ) -> tuple[list[dict], dict[str, list[float]], str]:
    """Every prefix m = 0, 1, ... of ``result``'s boxes: its verdict and each planner's row,
    until every planner is at PSR 0; returns the prefixes, the PSR curves and why it stopped."""
    from advocc_ros.attack.goals import goal_samples
    from advocc_ros.evaluation.runner import evaluate_planner

    boxes, centers = result.obstacles, result.centers_m
    samples = goal_samples(task.robot, task.scene.objects, task.scene.goal)
    budgets, psr = [], {p: [] for p in cfg.planners}
    for m in range(len(boxes) + 1):
        solvability = task.solvability(boxes[:m])
        entry = {'m': m, 'goal_valid_fraction':
                 samples.valid_fraction(centers[:m], result.box_size_m),
                 'solvable': solvability['verdict'], 'solvability': solvability,
                 'planners': {}}
        attacked = task.scene.with_objects(boxes[:m])
        for planner in cfg.planners:
            row = evaluate_planner(attacked, planner, cfg.trials, cfg.time_budget_s,
                                   seed=cfg.seed, workers=cfg.workers,
                                   planning_config=planning_config)
            entry['planners'][planner] = _row(row)
            psr[planner].append(row['psr'])
            if progress:
                progress(m, planner, entry['planners'][planner])
        budgets.append(entry)
        if all(entry['planners'][p]['psr'] == 0 for p in cfg.planners):
            return budgets, psr, f'every planner at PSR 0 % with m = {m}'
    return budgets, psr, f'evaluated every prefix up to the {len(boxes)} boxes placed'


def _impossible(task: _Task, result, same_attack: bool, known: dict[int, dict]) -> dict:
    """The fewest of a paper-policy attack's boxes that block the goal: its prefixes' verdicts
    up to the first ``goal blocked`` (``known``: verdicts already computed, by m)."""
    prefixes = []
    for m in range(1, len(result.obstacles) + 1):
        solvability = known.get(m) or task.solvability(result.obstacles[:m])
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
