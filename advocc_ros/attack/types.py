"""Attack settings, status codes, results and errors."""

from __future__ import annotations

import dataclasses
import enum
import re
from typing import Any

import numpy as np

from advocc_ros.heatmap.config import HeatmapConfig
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.robot import RobotModel
from advocc_ros.model.scene import SceneObject, objects_to_data


POLICIES = ('paper', 'reachable', 'solvable')
"""Goal policies (``advocc_ros.attack.policy``): the one list of their names."""
DEFAULT_METHOD = 'task'
"""The attack method of a request that names none: the paper's."""
BOX_ID = re.compile(r'adv_\d+')
"""Ids of the attack's boxes (``box_id``): a scene object may not carry one."""


def box_id(i: int) -> str:
    """Id of the attack's box ``i`` (pick order)."""
    return f'adv_{i}'


@dataclasses.dataclass(frozen=True)
class AttackConfig:
    """Online parameters; defaults from the paper (§V-A) and docs/design.md."""

    box_size_m: float = 0.05
    """s: edge of every adversarial box [m]."""
    corridor_radius_m: float = 0.3
    """r_corr: candidate centres lie within this distance of the start-goal segment [m]."""
    d_safe_m: float = HeatmapConfig.d_safe_m
    """Clearance of every box from the robot at q_init and from the goal region [m]."""
    d_min_m: float = 0.05
    """Minimum distance between box centres [m]."""
    max_budget: int = 100
    """Largest budget M a request may ask for."""
    max_box_m: float = 0.5
    """Largest box edge a request may ask for [m]."""
    protect_goal_hand: bool = False
    """Also keep d_safe from the hand at one IK solution for the goal centre (off: the paper's
    C3; the goal policy ``reachable`` is the measured way to keep the goal reachable)."""
    goal_policy: str = 'paper'
    """``paper`` (boxes may block every goal pose), ``reachable`` (see ``attack.goals``) or
    ``solvable`` (the task's witness path stays valid: ``attack.solvable``)."""
    reachable_fraction: float = 0.5
    """Under ``reachable``: share of the fixed goal samples that must stay valid."""
    victim_margin_m: float = 0.0
    """Distance every box keeps from the witness's body (and a ``joint`` goal's) on top of the
    certificate's guard margin [m]: the continuous witness then keeps this much more than the
    certificate's floor from every box, room for the victims' own collision models, whose link
    meshes are larger than our hulls (MPlib's FCL calls witnesses 1-4 mm clear under coal
    colliding). The boxes cannot move the scene: of the candidate witnesses, the policy keeps
    one that keeps this much from the scene when there is one (``attack.policy``)."""
    max_rejections: int = 500
    """Picks that fail the exact coal check before a method gives up (then PARTIAL)."""
    search_witness: bool = False
    """Under ``paper`` / ``reachable``: the edges (CLI, heatmap server, export) also find the
    task's witness (one RRTConnect run on the unattacked scene, in a planning worker, cached per
    task: ``attack.edges``) so the verdict can be ``certified``. Off: no planner is started and
    the verdict is judged without a witness. ``solvable`` always finds one; the audit and the
    benchmark always do (their tables count certified attacks)."""

    def __post_init__(self):
        checks = {'box_size_m': 0 < self.box_size_m <= self.max_box_m,
                  'corridor_radius_m': self.corridor_radius_m > 0,
                  'd_safe_m': self.d_safe_m >= 0, 'd_min_m': self.d_min_m >= 0,
                  'victim_margin_m': 0 <= self.victim_margin_m <= 0.05,
                  'max_budget': self.max_budget >= 1, 'max_box_m': self.max_box_m > 0,
                  'max_rejections': self.max_rejections >= 0,
                  'reachable_fraction': 0 <= self.reachable_fraction <= 1}
        if self.goal_policy not in POLICIES:
            raise ValueError(f'attack parameter goal_policy={self.goal_policy!r}: expected one '
                             f'of {list(POLICIES)}')
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or not np.isfinite(float(value)):
                raise ValueError(f'attack parameter {name}={value!r} is out of range')


@dataclasses.dataclass(frozen=True)
class Task:
    """One attack's task as every step of the pipeline reads it (docs/design.md): the robot,
    the scene, the start, the goal, and the two choices that change what the steps do, the goal
    policy and the goal form (data, so each step branches on them in one place)."""

    robot: RobotModel
    objects: tuple[SceneObject, ...]
    q_init: np.ndarray
    goal: GoalRegion
    policy: str = 'paper'
    """One of :data:`POLICIES`."""

    def __post_init__(self):
        if self.policy not in POLICIES:
            raise ValueError(f'goal policy {self.policy!r}: expected one of {list(POLICIES)}')

    @property
    def goal_form(self) -> str:
        """The goal's form (``model.goal.GOAL_FORMS``: ``region`` or ``joint``,
        docs/goal_forms.md), data the steps branch on, each in one place."""
        return self.goal.form


class AttackStatus(enum.Enum):
    """Outcome of an attack request; errors are data (the node maps them to ErrorCodes)."""

    SUCCESS = 'success'
    PARTIAL = 'partial'                      # fewer than M boxes fit the search region
    INVALID_REQUEST = 'invalid_request'      # budget, box size, non-finite numbers
    UNKNOWN_METHOD = 'unknown_method'
    INVALID_START = 'invalid_start'          # wrong joints, out of limits
    START_IN_COLLISION = 'start_in_collision'
    INVALID_GOAL = 'invalid_goal'            # empty or malformed goal region
    INVALID_LINK = 'invalid_link'            # goal link not in the robot
    ROBOT_MISMATCH = 'robot_mismatch'        # heatmap built for another robot
    INTERNAL_ERROR = 'internal_error'        # a planner-in-the-loop backend kept failing
    NO_WITNESS = 'no_witness'                # solvable policy without the task's witness

    @property
    def ok(self) -> bool:
        return self in (AttackStatus.SUCCESS, AttackStatus.PARTIAL)


@dataclasses.dataclass(frozen=True)
class AttackResult:
    """Obstacles placed by one attack, the mass each covered, and what it cost."""

    status: AttackStatus
    message: str = ''
    obstacles: tuple[SceneObject, ...] = ()
    """Boxes ``adv_0``, ``adv_1``, ... in pick order (robot base frame)."""
    masses: tuple[float, ...] = ()
    """Heatmap mass each box added to the coverage (marginal, in pick order)."""
    total_mass: float = 0.0
    compute_s: float = 0.0
    """Core time: search region, selection and exact checks (no file or message I/O)."""
    method: str = ''
    budget: int = 0
    box_size_m: float = 0.0
    stats: dict = dataclasses.field(default_factory=dict)
    """Diagnostics: candidate counts per filter, rejected picks, goal IK outcome."""
    goal_policy: str = ''
    goal_form: str = ''
    """``region`` or ``joint`` (``model.goal.GOAL_FORMS``): how the attacked task's goal is
    posed."""
    goal_valid_fraction: float | None = None
    """Of the task's fixed goal samples valid without the boxes, the fraction still valid with
    them (``attack.goals``); None when the goal region has no IK solution."""
    solvable: Any = None
    """``attack.solvable.Solvability``: certified / goal blocked / unknown (None: not
    assessed)."""
    witness: Any = None
    """``planning.witness.Witness`` handed to the attack, the one the verdict was judged with
    (None: none was given)."""

    @property
    def centers_m(self) -> np.ndarray:
        return np.array([o.shapes[0].pose.position_m for o in self.obstacles]).reshape(-1, 3)

    def to_json(self) -> dict:
        return {'status': self.status.value, 'message': self.message, 'method': self.method,
                'budget': self.budget, 'box_size_m': self.box_size_m,
                'obstacles': objects_to_data(self.obstacles),
                'masses': [float(m) for m in self.masses], 'total_mass': float(self.total_mass),
                'compute_ms': round(self.compute_s * 1e3, 3), 'goal_policy': self.goal_policy,
                'goal_form': self.goal_form,
                'goal_valid_fraction': self.goal_valid_fraction,
                'solvable': self.solvable.to_json() if self.solvable is not None else None,
                'stats': self.stats}


class AttackError(ValueError):
    """A request that cannot be attacked; ``status`` says why."""

    def __init__(self, status: AttackStatus, message: str):
        super().__init__(message)
        self.status = status
