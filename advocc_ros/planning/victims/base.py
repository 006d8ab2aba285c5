"""The victim protocol's data (``Task``, ``VictimConfig``, ``Victim``) and what every victim
shares: the goal list of a trial and the re-validation of a path in our model.

Re-exported by ``advocc_ros.planning.victims``, whose registry names the victims; victim modules
import from here, so the registry can import them without a cycle.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.scene import Scene
from advocc_ros.planning.types import PlanResult, PlanningConfig


@dataclasses.dataclass(frozen=True)
class Task:
    """One planning task handed to a victim."""

    scene: Scene
    """Objects (the attack's boxes included) and the robot (locked joints) [base frame, m]."""
    q_start: np.ndarray
    """(nq,) start configuration of the planned joints [rad]."""
    goal: GoalRegion
    """Goal region of the end-effector link."""
    goal_configs: np.ndarray | None = None
    """(K, nq) goal configurations to hand to victims that take configurations [rad]; None:
    the goal's configuration (``joint`` form), else the trial's goal list found before the
    clock (``advocc_ros.planning.goal_list``)."""

    def goal_list(self, robot, world, k: int, seed: int):
        """The ``GoalList`` of a trial: the given configurations, a ``joint`` goal's
        configuration (every victim is handed the goal itself: its PSR is path search alone),
        else up to K found before the clock from ``seed`` (our sampler in ``world``, with the
        boxes; the same for every victim of the trial)."""
        from advocc_ros.planning.goal_list import GoalList, goal_list
        if self.goal_configs is not None:
            given = np.asarray(self.goal_configs, dtype=float).reshape(-1, robot.nq)
            return GoalList(given, 0, 0, 0.0)
        if self.goal.is_joint:  # a goal the boxes block is no goal: "no goal found"
            q_goal = self.goal.configuration(robot.joint_names)[None]
            return GoalList(q_goal[~world.collisions_batch(q_goal)], 0, 0, 0.0)
        return goal_list(robot, world, self.goal, k, seed, self.scene.objects_hash())

    def goals(self, robot, world, k: int, seed: int) -> np.ndarray:
        """(k, nq) configurations of :meth:`goal_list`."""
        return self.goal_list(robot, world, k, seed).configs


@dataclasses.dataclass(frozen=True)
class VictimConfig:
    """Settings shared by the victims (ours keeps its own ``PlanningConfig``)."""

    planning: PlanningConfig = PlanningConfig()
    """Our OMPL planners' settings (also the watchdog margin and worker start-up time)."""
    goal_configs: int = 32
    """K: goal configurations given to victims that take only configurations."""
    ompl_goal_list: bool = False
    """Our OMPL planners plan to the same K goal configurations instead of sampling the goal
    region inside their budget (like for like with the outside victims)."""
    check_step_rad: float = 0.01
    """Joint-space step of the re-validation of an outside victim's path, in our model and in
    its own [rad] (``PlanningConfig.motion_step_rad``: our planners' own motion check)."""
    mplib_python: str = ''
    """Interpreter of the MPlib venv; empty: ``$ADVOCC_MPLIB_PYTHON``, else the checkout's
    ``.venv-mplib/bin/python`` (``make install`` creates it)."""
    ompl2_python: str = ''
    """Interpreter of the OMPL 2 venv (``aorrtc``, ``rrtconnect2``); empty:
    ``$ADVOCC_OMPL2_PYTHON``, else the checkout's ``.venv-ompl2/bin/python``."""
    hidden_object_ids: tuple[str, ...] = ()
    """Diagnostics only: objects left out of an outside victim's world (the tests of the
    re-validation hide a box from MPlib that our checker still sees)."""

    def __post_init__(self):
        if not (isinstance(self.goal_configs, int) and self.goal_configs >= 1):
            raise ValueError(f'goal_configs={self.goal_configs!r}: expected an integer >= 1')
        if not self.check_step_rad > 0:
            raise ValueError(f'check_step_rad={self.check_step_rad!r}: expected > 0')


class Victim(Protocol):
    """What the evaluation, the audit, the bench and the planner shim need from a planner."""

    name: str

    def start(self, scene: Scene) -> 'Victim':
        """Load ``scene``'s robot and start worker processes now (else the first request
        does)."""

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        """Plan ``task`` within ``time_budget_s`` [s]; never raises for a planning outcome."""

    def close(self) -> None:
        """Stop worker processes."""


def goal_configurations(robot, world, goal: GoalRegion, k: int, seed: int) -> np.ndarray:
    """(<= k, nq) collision-free goal configurations in ``goal`` for ``world`` (our model, with
    the boxes), from ``seed`` alone: the configurations of the trial's goal list
    (:meth:`Task.goal_list`), searched again."""
    from advocc_ros.planning.goal_list import search_goal_list
    return search_goal_list(robot, world, goal, k, seed).configs


def densify(path: np.ndarray, step_rad: float) -> np.ndarray:
    """``path`` (N, nq) linearly interpolated so consecutive states are <= ``step_rad`` apart."""
    path = np.asarray(path, dtype=float)
    if len(path) < 2:
        return path
    out = []
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_rad)))
        out.append(a + (b - a) * (np.arange(n) / n)[:, None])
    out.append(path[-1:])
    return np.vstack(out)


def first_collision_along(world, path: np.ndarray, step_rad: float) -> int:
    """Index of the first colliding state of ``path`` densified at ``step_rad`` in ``world``
    (our exact checker: SRDF self-collision + scene, on the convex hulls); -1 if none."""
    return int(world.first_collision(densify(path, step_rad)))


def path_length_rad(path: np.ndarray) -> float:
    """Joint-space length of a path [rad]."""
    path = np.asarray(path, dtype=float)
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0


__all__ = ['Task', 'Victim', 'VictimConfig', 'densify', 'first_collision_along',
           'goal_configurations', 'path_length_rad']
