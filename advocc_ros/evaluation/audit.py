"""The audit: how few boxes make a planner fail one task, and where do they go.

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

from advocc_ros.evaluation.metrics import minimal_budgets

log = logging.getLogger(__name__)

ANSWER_THRESHOLD = 0.2
"""A planner "fails" the task when its PSR is at most this (the answer's headline)."""
AUDIT_FORMAT = 'advocc_audit'
AUDIT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class AuditConfig:
    """What one audit runs: the attack, the victims and the trials."""

    planners: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1')
    """OMPL planner ids evaluated at every prefix."""
    max_budget: int = 5
    """K: boxes of the one attack whose prefixes are evaluated."""
    trials: int = 10
    """Plan requests per planner and prefix."""
    time_budget_s: float = 5.0
    """Wall-clock budget of one plan request [s] (the paper: 5)."""
    method: str = 'task'
    """Attack method (``advocc_ros.attack.methods.REGISTRY``); greedy ones give nested picks."""
    policy: str = 'paper'
    """Goal policy of the attack: ``paper`` or ``reachable`` (``advocc_ros.attack.goals``)."""
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
    keys = ('psr', 'successes', 'trials', 'pt', 'smr', 'cmr', 'jds', 'failures')
    return {k: result[k] for k in keys}


def run_audit(scene, heatmap, cfg: AuditConfig = AuditConfig(),
              progress: Callable[[int, str, dict], None] | None = None,
              attack_cfg=None, planning_config=None) -> dict[str, Any]:
    """One attack at budget ``cfg.max_budget`` on ``scene``'s task, then every prefix m = 0, 1,
    ... evaluated per planner (see the module docstring); returns the JSON-able audit.

    ``progress(m, planner, row)`` is called after each evaluation. Raises ``ValueError`` when the
    attack cannot run (its status and message) or the scene has no start or goal.
    """
    import numpy as np

    from advocc_ros.attack import AttackConfig, attack
    from advocc_ros.attack.goals import goal_samples
    from advocc_ros.attack.methods import REGISTRY
    from advocc_ros.evaluation.metrics import evaluate_planner
    from advocc_ros.evaluation.perf import machine
    from advocc_ros.model import load_robot, start_configuration

    if scene.goal is None or scene.start is None:
        raise ValueError(f'scene {scene.name!r} needs a start and a goal to be audited')
    if cfg.method not in REGISTRY:
        raise ValueError(f'unknown attack method {cfg.method!r}; known: {list(REGISTRY)}')
    attack_cfg = attack_cfg or AttackConfig()
    t_start = time.perf_counter()
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    result = attack(heatmap, robot, scene.objects, q_init, scene.goal, cfg.max_budget,
                    cfg.method, attack_cfg, seed=cfg.seed, goal_policy=cfg.policy)
    if not result.status.ok:
        raise ValueError(f'attack {cfg.method} failed: {result.status.value}: {result.message}')
    boxes = result.obstacles
    centers = result.centers_m
    samples = goal_samples(robot, scene.objects, scene.goal)
    log.info('audit %s: %d boxes (%s), evaluating prefixes', scene.name, len(boxes),
             result.status.value)

    budgets, psr = [], {p: [] for p in cfg.planners}
    stop_reason = f'evaluated every prefix up to the {len(boxes)} boxes placed'
    for m in range(len(boxes) + 1):
        attacked = scene.with_objects(boxes[:m])
        entry = {'m': m, 'goal_valid_fraction':
                 samples.valid_fraction(centers[:m], result.box_size_m), 'planners': {}}
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
            stop_reason = f'every planner at PSR 0 % with m = {m}'
            break

    return {
        'format': AUDIT_FORMAT, 'version': AUDIT_VERSION,
        'scene': scene.name, 'scene_hash': scene.objects_hash(),
        'method': cfg.method, 'method_label': REGISTRY[cfg.method].label, 'policy': cfg.policy,
        'max_budget': cfg.max_budget,
        'settings': dict(dataclasses.asdict(cfg), planners=list(cfg.planners),
                         box_size_m=result.box_size_m,
                         heatmap={k: heatmap.meta.get(k) for k in
                                  ('valid_samples', 'scene_name', 'build_s')}),
        'attack': {'status': result.status.value, 'message': result.message,
                   'compute_ms': round(result.compute_s * 1e3, 3),
                   'total_mass': float(result.total_mass),
                   'goal_valid_fraction': result.goal_valid_fraction, 'stats': result.stats},
        'boxes': [{'pick': i + 1, 'id': obj.id,
                   'center_m': [round(float(v), 4) for v in np.asarray(c)],
                   'size_m': result.box_size_m, 'mass': float(mass)}
                  for i, (obj, c, mass) in enumerate(zip(boxes, centers, result.masses))],
        'budgets': budgets,
        'psr': psr,
        'min_budget': minimal_budgets(psr),
        'stopped': stop_reason,
        'wall_s': round(time.perf_counter() - t_start, 2),
        'machine': machine(),
    }
