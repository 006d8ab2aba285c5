"""The benchmark's protocol and run plan (paper §V; docs/metrics.md); see ``advocc_ros.bench``.

- ``BenchConfig``: one protocol (a profile of ``config/bench.yaml`` plus command-line overrides).
- ``plan_units``: the run plan. A *unit* is one planning scene to inject (an attack, or none for
  the unattacked baseline) and the trials to run in it. Attacks that do not depend on the victim
  (ours, random, pfa) serve every planner from one injection; planner-specific ones (pfa++) get
  one unit per planner. A method with ``variants: R`` splits a cell's trials into R contiguous
  blocks, each against its own attack (seed + v), so a Random cell is not one lucky draw.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import pathlib
import re
from typing import Iterable, NoReturn

import yaml

from advocc_ros.attack.methods import REGISTRY
from advocc_ros.attack.types import POLICIES
from advocc_ros.heatmap.config import HeatmapConfig
from advocc_ros.limits import MAX_TRIALS
from advocc_ros.planning.victims import OUTSIDE_LABELS

log = logging.getLogger(__name__)

BASELINE = 'none'
"""Method name of the unattacked baseline (budget 0)."""
METHOD_LABELS = {name: spec.label for name, spec in REGISTRY.items()} | {BASELINE: 'None'}
PLANNER_LABELS = {'rrtconnect': 'RRT', 'prmstar': 'PRM*', 'bkpiece1': 'BKPIECE',
                  **OUTSIDE_LABELS}
MAX_BUDGET = 90
"""Largest budget: one attack's REMOVE + ADDs must fit the latched topic's history (100)."""
# Settings that change what a trial measures: a run folder refuses to mix them.
IDENTITY_FIELDS = ('time_budget_s', 'seed', 'box_size_m', 'heatmap_samples',
                   'heatmap_robot_only', 'variants', 'goal_policy', 'task', 'victim_margin_m')


class BenchError(ValueError):
    """A protocol, profile or run folder that cannot be used; the message says why."""


def _fail(what: str) -> NoReturn:
    """Refuse a setting: ``BenchError`` naming it and why."""
    raise BenchError(f'bench setting {what}')


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """One benchmark protocol; defaults are the paper's (§V-A)."""

    scenes: tuple[str, ...] = ('table_pick', 'table_under_pick', 'bookshelf')
    """Scene names (config/scenes) or scene YAML paths; 'Scene i' in tables is 1-based order."""
    planners: tuple[str, ...] = ('rrtconnect', 'prmstar', 'bkpiece1')
    methods: tuple[str, ...] = ('ours', 'random', 'pfa', 'pfa++')
    budgets: tuple[int, ...] = (1, 3, 5)
    """Budgets M of Table I (trials each)."""
    trials: int = 500
    """Trials per (scene, planner, method, budget) cell and for the baseline."""
    time_budget_s: float = 5.0
    """Planning budget of one trial [s]; a failure counts this as PT."""
    sweep_budgets: tuple[int, ...] = ()
    """Extra budgets for Table II's budget-to-failure sweep (with ``budgets`` and 0)."""
    sweep_trials: int | None = None
    """Trials of a sweep-only budget (None: ``trials``)."""
    baseline: bool = True
    """Also run the unattacked scene (budget 0) per scene x planner."""
    variations: int = 0
    """Table II also runs this many seeded variations of each scene (``advocc scenes vary``,
    seed ``seed``) at every budget, and averages the minimal budgets over the scene and its
    variations (fractional budgets, like the paper's)."""
    variants: dict = dataclasses.field(default_factory=dict)
    """Attacks per cell by method (e.g. random: 10); trials are split between them."""
    planner_specific: tuple[str, ...] = ('pfa++',)
    """Methods whose attack queries the victim planner: one attack per planner."""
    skip: tuple[str, ...] = ('pfa++:rrtconnect',)
    """``method:planner`` pairs not run ("--" in the tables; PFA++ on RRT is PFA)."""
    seed: int = 0
    """Trial k plans with seed ``seed + k``; attack variant v uses seed ``seed + v``."""
    shims: int = 2
    """Local planner_shim processes per scene."""
    external_shims: bool = False
    """Also use planner shims of the same ROS domain found by their ``*/plan`` services."""
    heatmap_samples: int = HeatmapConfig.samples
    heatmap_robot_only: bool = False
    heatmap_workers: int = 2
    box_size_m: float = 0.0
    """Box edge [m]; 0: the heatmap server's default (0.05 m)."""
    goal_policy: str = 'paper'
    """Goal policy of the coverage attacks: ``paper`` or ``reachable`` (``attack.policy``)."""
    victim_margin_m: float = 0.0
    """Distance every box keeps from the witness and a joint goal beyond the certificate's guard
    [m] (``AttackConfig.victim_margin_m``: room for a victim's own collision model, MPlib's FCL
    among them; the data set's 0.004), given to the heatmap server and the in-the-loop
    attacks."""
    attack_timeout_s: float = 300.0
    """Longest wait for one attack [s]: the planner-in-the-loop methods (PFA, PFA++) need long
    ones."""
    start_timeout_s: float = 120.0
    """Longest wait for a started node's services [s]."""
    plan_timeout_margin_s: float = 30.0
    """A plan request unanswered ``time_budget_s`` + this long marks its shim as hung [s]."""
    max_restarts: int = 5
    """Restarts of one node per scene before the benchmark gives up."""
    pfa: dict = dataclasses.field(default_factory=dict)
    """Settings of the planner-in-the-loop methods (``advocc_ros.attack.pfa.PfaConfig`` fields:
    queries, queries_per_placement, query_time_s, ...); their queries run on the shims."""
    task: dict = dataclasses.field(default_factory=dict)
    """Options of the ``task`` attacks (``advocc_ros.attack.task.TaskOptions`` fields, e.g.
    ``{tube_samples: 512}``), given to the heatmap server as its ``task_<option>`` parameters; the
    others keep their defaults."""

    def __post_init__(self):
        self._check_names()
        self._check_budgets()
        self._check_counts()
        self._check_times()
        self._check_attacks()

    def _check_names(self) -> None:
        """Scenes, planners and methods: non-empty lists of distinct names, known victims, and
        no outside victim in the loop of a planner-specific attack."""
        for name in ('scenes', 'planners', 'methods'):
            value = getattr(self, name)
            if not value or not all(isinstance(v, str) and v for v in value):
                _fail(f'{name}: expected a non-empty list of names, got {value!r}')
            if len(set(value)) != len(value):
                _fail(f'{name}: duplicates in {list(value)}')
        from advocc_ros.planning.victims import is_outside, is_victim
        unknown = [p for p in self.planners if not is_victim(p)]
        if unknown:
            _fail(f'planners: unknown {unknown}; OMPL planner ids or outside victims '
                  '(advocc_ros.planning.victims)')
        in_loop = [f'{m}:{p}' for m in self.planner_specific if m in self.methods
                   for p in self.planners if is_outside(p) and f'{m}:{p}' not in self.skip]
        if in_loop:
            _fail(f'planners: {in_loop} would put an outside victim in the loop of a '
                  'planner-specific attack, which queries our OMPL planners only; add them to '
                  'skip')

    def _check_budgets(self) -> None:
        """Budgets in 1..MAX_BUDGET, and something to run."""
        for name in ('budgets', 'sweep_budgets'):
            for b in getattr(self, name):
                if isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= MAX_BUDGET:
                    _fail(f'{name}: budgets must be integers in 1..{MAX_BUDGET}, got {b!r}')
        if not self.budgets and not self.sweep_budgets and not self.baseline:
            _fail('budgets: nothing to run')

    def _check_counts(self) -> None:
        """Trials, processes, samples and variations: integers in range; someone plans."""
        for name in ('trials', 'shims', 'heatmap_samples', 'heatmap_workers', 'variations'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (
                    0 if name in ('shims', 'variations') else 1):
                _fail(f'{name}={value!r} is out of range')
        if self.trials > MAX_TRIALS:
            _fail(f'trials={self.trials} exceeds the limit {MAX_TRIALS} (limits.MAX_TRIALS)')
        if self.sweep_trials is not None and (not isinstance(self.sweep_trials, int)
                                              or not 1 <= self.sweep_trials <= MAX_TRIALS):
            _fail(f'sweep_trials={self.sweep_trials!r} must be an integer in 1..{MAX_TRIALS}')
        if self.shims == 0 and not self.external_shims:
            _fail('shims=0 needs external_shims: nobody would plan')

    def _check_times(self) -> None:
        """The planning budget and the timeouts: finite and > 0 [s]."""
        for name in ('time_budget_s', 'attack_timeout_s', 'start_timeout_s',
                     'plan_timeout_margin_s'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                _fail(f'{name}={value!r} must be a finite number > 0')

    def _check_attacks(self) -> None:
        """The attacks' settings: box size, PFA and task options, variants, goal policy, skip."""
        if not (isinstance(self.box_size_m, (int, float)) and 0 <= self.box_size_m <= 0.5):
            _fail(f'box_size_m={self.box_size_m!r} must be in [0, 0.5] (0: server default)')
        if not isinstance(self.pfa, dict) or 'planner_id' in self.pfa:
            _fail(f'pfa: expected a mapping of PfaConfig settings (the planner is the cell\'s), '
                  f'got {self.pfa!r}')
        from advocc_ros.attack.task import task_options
        try:
            task_options(self.task)
        except ValueError as exc:
            _fail(f'task: {exc}')
        if not isinstance(self.variants, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1
                for v in self.variants.values()):
            _fail(f'variants: expected method: count >= 1, got {self.variants!r}')
        if self.goal_policy not in POLICIES:
            _fail(f'goal_policy={self.goal_policy!r}: expected one of {list(POLICIES)}')
        if not (isinstance(self.victim_margin_m, (int, float))
                and not isinstance(self.victim_margin_m, bool)
                and 0.0 <= self.victim_margin_m <= 0.05):
            _fail(f'victim_margin_m={self.victim_margin_m!r}: expected a number in [0, 0.05] m')
        for pair in self.skip:
            if not isinstance(pair, str) or pair.count(':') != 1:
                _fail(f'skip: expected "method:planner" entries, got {pair!r}')

    @property
    def all_budgets(self) -> tuple[int, ...]:
        return tuple(sorted(set(self.budgets) | set(self.sweep_budgets)))

    def trials_for(self, budget: int, scene: str | None = None) -> int:
        """Trials of a cell; a variation scene (not in ``scenes``) is Table II only."""
        if scene is not None and scene not in self.scenes:
            return self.sweep_trials or self.trials
        if budget == 0 or budget in self.budgets or self.sweep_trials is None:
            return self.trials
        return self.sweep_trials

    def skipped(self, method: str, planner: str) -> bool:
        return f'{method}:{planner}' in self.skip

    def to_data(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_data(cls, data: dict, where: str = 'bench config') -> 'BenchConfig':
        if not isinstance(data, dict):
            raise BenchError(f'{where}: expected a mapping, got {type(data).__name__}')
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise BenchError(f'{where}: unknown settings {unknown}; known: {sorted(names)}')
        values = {}
        for key, value in data.items():
            if key in ('scenes', 'planners', 'methods', 'budgets', 'sweep_budgets',
                       'planner_specific', 'skip'):
                if not isinstance(value, (list, tuple)):
                    raise BenchError(f'{where}.{key}: expected a list, got {value!r}')
                value = tuple(value)
            values[key] = value
        try:
            return cls(**values)
        except TypeError as exc:
            raise BenchError(f'{where}: {exc}') from None


def load_profile(path: str | pathlib.Path, name: str) -> BenchConfig:
    """Profile ``name`` of a bench YAML file (``profiles: {name: {setting: value}}``)."""
    path = pathlib.Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BenchError(f'{path}: cannot read ({exc})') from None
    profiles = data.get('profiles') if isinstance(data, dict) else None
    if not isinstance(profiles, dict) or not profiles:
        raise BenchError(f'{path}: expected a mapping with profiles: {{name: settings}}')
    if name not in profiles:
        raise BenchError(f'{path}: no profile {name!r}; profiles: {sorted(profiles)}')
    return BenchConfig.from_data(profiles[name] or {}, f'{path}:{name}')


# --------------------------------------------------------------------------------------------
# Run plan

@dataclasses.dataclass(frozen=True)
class AttackSpec:
    """One attack to generate (and cache in the run folder)."""

    scene: str
    method: str
    budget: int
    variant: int = 0
    planner: str | None = None
    """Victim planner of a planner-specific attack (pfa++), else None."""
    seed: int = 0

    @property
    def tag(self) -> str:
        """File-name and object-id safe name, unique within a scene."""
        method = self.method.replace('+', 'p')
        planner = f'_{self.planner}' if self.planner else ''
        return re.sub(r'[^A-Za-z0-9_]', '_', f'{method}_b{self.budget}{planner}_v{self.variant}')


@dataclasses.dataclass(frozen=True)
class Trial:
    """One plan request of the protocol."""

    scene: str
    planner: str
    method: str
    budget: int
    trial: int
    seed: int

    @property
    def key(self) -> str:
        return trial_key(self.scene, self.planner, self.method, self.budget, self.trial)

    @property
    def cell(self) -> tuple[str, str, str, int]:
        return self.scene, self.planner, self.method, self.budget


def trial_key(scene: str, planner: str, method: str, budget: int, trial: int) -> str:
    return f'{scene}|{planner}|{method}|{int(budget)}|{int(trial)}'


@dataclasses.dataclass
class Unit:
    """A planning scene to inject (``attack`` None: the unattacked scene) and its trials."""

    scene: str
    attack: AttackSpec | None
    trials: list[Trial]


def scene_label(cfg: BenchConfig, scene: str) -> str:
    name = pathlib.Path(scene).stem if scene.endswith(('.yaml', '.yml')) else scene
    return f'Scene {cfg.scenes.index(scene) + 1} ({name})'


def variation_scenes(cfg: BenchConfig, run_dir: str | pathlib.Path) -> dict[str, list[str]]:
    """Scene files of ``cfg.variations`` seeded variations per scene, written once into
    ``run_dir/scenes/`` (re-used on resume): base scene -> files."""
    from advocc_ros.model.scene import load_scene
    from advocc_ros.scenes.variations import write_variation
    from advocc_ros.paths import scene_path

    out: dict[str, list[str]] = {}
    folder = pathlib.Path(run_dir) / 'scenes'
    for scene in cfg.scenes if cfg.variations else ():
        base = load_scene(scene_path(scene))
        files = []
        for index in range(cfg.variations):
            path = folder / f'{base.name}_{index:04d}.yaml'
            if not path.exists():
                path, _ = write_variation(base, index, cfg.seed, folder)
            files.append(str(path))
        out[scene] = files
    return out


def check_tasks(scenes: Iterable[str]) -> None:
    """``BenchError`` naming the scene and the reason when a scene's task is refused by
    ``model.task_check`` (start outside the limits or in collision, naming the pair): checked
    before any heatmap, node or trial, so a wrong task is never scored as internal errors."""
    from advocc_ros.kinematics.ik import start_configuration
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import load_scene
    from advocc_ros.model.task_check import check_task
    from advocc_ros.paths import scene_path

    for name in scenes:
        scene = load_scene(scene_path(name))
        if scene.start is None or scene.goal is None:
            raise BenchError(f'scene {name}: a benchmark scene needs a start and a goal')
        robot = load_robot(scene.robot)
        fault = check_task(robot, scene.objects, start_configuration(scene, robot), scene.goal)
        if fault is not None:
            raise BenchError(f'scene {name}: the task is refused: {fault.message}')


def plan_units(cfg: BenchConfig, available: Iterable[str] | None = None,
               variations: dict[str, list[str]] | None = None
               ) -> tuple[list[Unit], list[str]]:
    """The run plan in execution order (scene-major) and notes on what is skipped and why.

    ``available``: methods that can be generated (None: all); the others are skipped.
    ``variations``: base scene -> variation scene files (:func:`variation_scenes`); each runs
    every budget of Table II with ``trials_for`` trials, after its base scene.
    """
    available = set(cfg.methods if available is None else available)
    notes = []
    if cfg.goal_policy != 'paper':
        for method in [m for m in cfg.methods if m in available
                       and REGISTRY.get(m) and REGISTRY[m].queries_planner]:
            available.discard(method)
            notes.append(f'method {method!r} skipped: the goal policy {cfg.goal_policy} applies '
                         'to the coverage methods')
    for method in cfg.methods:
        if method not in available and not (cfg.goal_policy != 'paper' and REGISTRY.get(
                method) and REGISTRY[method].queries_planner):
            notes.append(f'method {method!r} skipped: not available in this installation')
    for pair in cfg.skip:
        method, planner = pair.split(':')
        if method in cfg.methods and planner in cfg.planners:
            notes.append(f'{method} on {planner} not run (configured skip: {pair})')
    units: list[Unit] = []
    scenes = [s for base in cfg.scenes for s in [base, *(variations or {}).get(base, [])]]
    for scene in scenes:
        if cfg.baseline or scene not in cfg.scenes:
            trials = [Trial(scene, p, BASELINE, 0, k, cfg.seed + k)
                      for p in cfg.planners for k in range(cfg.trials_for(0, scene))]
            units.append(Unit(scene, None, trials))
        for method in cfg.methods:
            if method not in available:
                continue
            planners = [p for p in cfg.planners if not cfg.skipped(method, p)]
            groups = [[p] for p in planners] if method in cfg.planner_specific else [planners]
            for budget in cfg.all_budgets:
                n = cfg.trials_for(budget, scene)
                n_var = max(1, min(int(cfg.variants.get(method, 1)), n))
                for group in groups:
                    if not group:
                        continue
                    for v in range(n_var):
                        spec = AttackSpec(scene, method, budget, v,
                                          group[0] if method in cfg.planner_specific else None,
                                          cfg.seed + v)
                        ks = [k for k in range(n) if k * n_var // n == v]
                        units.append(Unit(scene, spec, [Trial(scene, p, method, budget, k,
                                                              cfg.seed + k)
                                                        for p in group for k in ks]))
    return units, notes
