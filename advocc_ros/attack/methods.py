"""The attack methods: one registry of names, selectors and what they need.

The registry itself loads no compiled kernel (the nodes validate method names with it); the
selectors import the coverage kernels when they run."""

from __future__ import annotations

import dataclasses
import importlib
import logging
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from advocc_ros.attack.types import AttackConfig, Task

if TYPE_CHECKING:
    from advocc_ros.attack.region import SearchRegion

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Methods

Selector = Callable[..., tuple]
"""``(region, budget, seed, cfg[, context]) -> ([(window index, mass), ...], rejected picks[,
stats])``; ``context`` (a :class:`MethodContext`) only for methods registered with
``needs_context``; ``stats``, the method's own statistics, when it has some (the attack gathers
them with the other steps')."""


@dataclasses.dataclass(frozen=True)
class MethodContext(Task):
    """The task behind a search region and what the earlier steps made of it, for the methods
    that read more than the region (``task``, PFA, PFA++; ``ours`` and ``random`` never get
    it: they choose from the heatmap and the region alone)."""

    options: Any = None
    """Method-specific settings from ``attack(method_options=...)`` (e.g. a planner)."""
    sample: Any = None
    """The task sample (``attack.task.TaskSample``) when the method or the policy needs it."""
    policed: Any = None
    """What the goal policy kept (``attack.policy.Policed``): the witness, its body, ..."""

    @classmethod
    def of(cls, task: Task, options: Any = None, sample: Any = None, policed: Any = None
           ) -> 'MethodContext':
        """The context of ``task`` with the steps' data."""
        fields = {f.name: getattr(task, f.name) for f in dataclasses.fields(Task)}
        return cls(**fields, options=options, sample=sample, policed=policed)


def _select_greedy(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig):
    from advocc_ros.attack.coverage import greedy_cover
    return greedy_cover(region.weights, region.candidates, region.k, budget,
                        region.d_min_m / region.grid.voxel_m, region.accept, cfg.max_rejections)


def _select_random(region: SearchRegion, budget: int, seed: int, cfg: AttackConfig):
    from advocc_ros.attack.coverage import random_cover
    return random_cover(region.weights, region.candidates, region.k, budget,
                        region.d_min_m / region.grid.voxel_m, np.random.default_rng(seed),
                        region.accept, cfg.max_rejections)


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    """Where an attack method lives and what its selector takes."""

    module: str
    """Module that registers the selector (:func:`register_method`) when imported."""
    label: str
    """Name in tables and figures."""
    needs_context: bool = False
    """The selector also takes ``context=MethodContext(...)`` (the task: robot, scene, q, G)."""
    queries_planner: bool = False
    """The method plans to choose its boxes (PFA, PFA++): a benchmark serves its queries."""
    needs_sample: bool = False
    """The method covers the task sample (``attack.task``): the attack draws it first."""


REGISTRY: dict[str, MethodSpec] = {
    'ours': MethodSpec('advocc_ros.attack.methods', 'Ours'),
    'random': MethodSpec('advocc_ros.attack.methods', 'Random'),
    'task': MethodSpec('advocc_ros.attack.objective', 'Task', needs_context=True,
                       needs_sample=True),
    'pfa': MethodSpec('advocc_ros.attack.pfa', 'PFA', needs_context=True, queries_planner=True),
    'pfa++': MethodSpec('advocc_ros.attack.pfa', 'PFA++', needs_context=True,
                        queries_planner=True),
}
"""Every attack method by name: the one list the CLI, the nodes and the benchmark use.
A new method adds one line here and calls :func:`register_method` in its module."""

KNOWN_METHODS = tuple(REGISTRY)
SERVER_METHODS = tuple(name for name, spec in REGISTRY.items() if not spec.queries_planner)
"""Methods a heatmap server runs on its own (no planner queries): the attacker node's choices."""

METHODS: dict[str, Selector] = {}
"""Selectors of the methods whose module is loaded (see :func:`load_method`)."""

CONTEXT_METHODS: set[str] = set()
"""Methods whose selector also takes ``context=MethodContext(...)``."""


def register_method(name: str, selector: Selector, needs_context: bool | None = None) -> None:
    """Make ``name`` usable; ``needs_context`` defaults to the :data:`REGISTRY` entry's."""
    if needs_context is None:
        needs_context = name in REGISTRY and REGISTRY[name].needs_context
    METHODS[name] = selector
    if needs_context:
        CONTEXT_METHODS.add(name)
    else:
        CONTEXT_METHODS.discard(name)


def load_method(name: str) -> bool:
    """Whether ``name`` is usable, importing its module if it is not loaded yet."""
    if name not in METHODS and name in REGISTRY:
        try:
            importlib.import_module(REGISTRY[name].module)
        except ModuleNotFoundError as exc:
            log.info('method %s is not available: %s', name, exc)
    return name in METHODS


def available_methods() -> list[str]:
    """The known methods that load here, sorted."""
    return sorted(name for name in KNOWN_METHODS if load_method(name))


register_method('ours', _select_greedy)
register_method('random', _select_random)
