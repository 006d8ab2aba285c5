"""Goal regions: a tolerance box around an end-effector pose (paper §III-A; docs/design.md)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pinocchio as pin

from advocc_ros.limits import MAX_GOAL_DISTANCE_M
from advocc_ros.model.pose import Pose, SceneError, finite_array
from advocc_ros.model.robot import RobotSpec


GOAL_FORMS = ('region', 'joint')
"""How a task's goal is posed (docs/design.md, "Goal forms"): ``region``, the paper's
tolerance-aware region (any configuration whose tool pose lies in it); ``joint``, one joint
configuration (a MotionBenchMaker request's own goal, as MoveIt, VAMP and MPlib plan to it)."""


def _rotation_error(R_center: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector of ``R`` relative to ``R_center`` (the MoveIt ROTATION_VECTOR form)."""
    return pin.log3(R_center.T @ R)


@dataclasses.dataclass(frozen=True)
class GoalRegion:
    """Tolerance box around an end-effector pose (paper §III-A; docs/design.md).

    A pose ``T_base_tool`` is inside when its position, expressed in the centre's frame, lies in
    the box ``|p| <= position_tolerance_m`` and the rotation vector of ``R_center^T R`` lies
    within ``orientation_tolerance_rad`` per axis (MoveIt's ``absolute_*_axis_tolerance`` with
    the rotation-vector parameterization).
    """

    center: Pose
    position_tolerance_m: tuple[float, float, float] = (0.02, 0.02, 0.02)
    orientation_tolerance_rad: tuple[float, float, float] = (0.1, 0.1, 0.1)
    link: str = RobotSpec.ee_link
    tool_offset: Pose = Pose()
    """Pose of the tool point in ``link``; the region constrains the tool point."""
    seed_joints: tuple[str, ...] = ()
    """Joint names of ``seeds``."""
    seeds: tuple[tuple[float, ...], ...] = ()
    """Goal configurations [rad | m] by ``seed_joints``, meant to lie in the region (a request's
    joint goal): the planners' goal sampler offers them first and seeds IK near them, the way
    MoveIt plans to a joint goal itself. The region stays the goal; a seed is only a hint.
    In the ``joint`` form the one seed is the goal."""
    form: str = 'region'
    """``region``: any configuration with the tool in the box; ``joint``: the configuration
    ``seeds[0]`` itself (within ``JOINT_TOLERANCE_RAD``); its tool pose is ``center``, which
    then only places the task (the corridor of C1, drawings)."""

    def __post_init__(self):
        finite_array(self.position_tolerance_m, 'goal.position_tolerance', 3, nonneg=True)
        finite_array(self.orientation_tolerance_rad, 'goal.orientation_tolerance', 3, nonneg=True)
        if not self.link:
            raise SceneError('goal.link: empty link name')
        if self.form not in GOAL_FORMS:
            raise SceneError(f'goal.form: {self.form!r}; known: {list(GOAL_FORMS)}')
        if self.form == 'joint' and len(self.seeds) != 1:
            raise SceneError(f'goal.form joint: the goal configuration is the one seed, got '
                             f'{len(self.seeds)} seeds')
        if self.seeds and not self.seed_joints:
            raise SceneError('goal.seeds: seeds without joint names')
        for k, seed in enumerate(self.seeds):
            finite_array(seed, f'goal.seeds[{k}]', len(self.seed_joints))
        for what, pose in (('center', self.center), ('tool_offset', self.tool_offset)):
            far_m = float(np.abs(pose.position_m).max())
            if far_m > MAX_GOAL_DISTANCE_M:
                raise SceneError(f'goal.{what}: a coordinate of {far_m:.3g} m, limit '
                                 f'{MAX_GOAL_DISTANCE_M:g} m (MAX_GOAL_DISTANCE_M)')

    @staticmethod
    def _seeds_from_data(data: Any, where: str) -> tuple[tuple[str, ...], tuple]:
        """(joint names, configurations) of ``seeds: [{joint: value, ...}, ...]``."""
        if data is None or data == []:
            return (), ()
        if not isinstance(data, list) or not all(isinstance(d, dict) and d for d in data):
            raise SceneError(f'{where}: expected a list of mappings joint_name: position')
        names = tuple(str(n) for n in data[0])
        seeds = []
        for k, seed in enumerate(data):
            if set(map(str, seed)) != set(names):
                raise SceneError(f'{where}[{k}]: joints {sorted(map(str, seed))} differ from '
                                 f'the first seed\'s {sorted(names)}')
            seed = {str(n): v for n, v in seed.items()}
            seeds.append(tuple(finite_array([seed[n] for n in names], f'{where}[{k}]').tolist()))
        return names, tuple(seeds)

    @classmethod
    def from_data(cls, data: Any, where: str = 'goal', default_link: str = RobotSpec.ee_link
                  ) -> 'GoalRegion':
        """``default_link``: the link of a region that names none (the robot's ``ee_link``)."""
        if not isinstance(data, dict):
            raise SceneError(f'{where}: expected a mapping')
        known = {'link', 'center', 'position_tolerance', 'orientation_tolerance', 'tool_offset',
                 'seeds', 'form'}
        unknown = set(data) - known
        if unknown:
            raise SceneError(f'{where}: unknown field(s) {sorted(unknown)}; '
                             f'known: {sorted(known)}')
        if 'center' not in data:
            raise SceneError(f'{where}.center: missing')
        link = data.get('link', default_link)
        if not isinstance(link, str) or not link:
            raise SceneError(f'{where}.link: expected a link name, got {link!r}')
        seed_joints, seeds = cls._seeds_from_data(data.get('seeds'), f'{where}.seeds')
        fields = dict(
                center=Pose.from_data(data['center'], f'{where}.center'),
                position_tolerance_m=tuple(finite_array(
                    data.get('position_tolerance', [0.02] * 3), f'{where}.position_tolerance', 3,
                    nonneg=True).tolist()),
                orientation_tolerance_rad=tuple(finite_array(
                    data.get('orientation_tolerance', [0.1] * 3), f'{where}.orientation_tolerance',
                    3, nonneg=True).tolist()),
                link=link,
                tool_offset=Pose.from_data(data.get('tool_offset'), f'{where}.tool_offset'),
                seed_joints=seed_joints, seeds=seeds, form=data.get('form', 'region'))
        try:
            return cls(**fields)
        except SceneError as exc:  # __post_init__'s checks know no file
            raise SceneError(f'{where}: {exc}') from None

    def to_data(self) -> dict:
        data = {'link': self.link, 'center': self.center.to_data(),
                'position_tolerance': list(self.position_tolerance_m),
                'orientation_tolerance': list(self.orientation_tolerance_rad),
                'tool_offset': self.tool_offset.to_data()}
        if self.seeds:  # absent otherwise: seedless goals keep their files and hashes
            data['seeds'] = [{n: float(v) for n, v in zip(self.seed_joints, seed)}
                             for seed in self.seeds]
        if self.form != 'region':  # absent for regions: their files and hashes stay the same
            data['form'] = self.form
        return data

    @property
    def is_joint(self) -> bool:
        """Whether the goal is one joint configuration (the ``joint`` form)."""
        return self.form == 'joint'

    def configuration(self, joint_names) -> np.ndarray:
        """The ``joint`` form's goal configuration in the order of ``joint_names``;
        ``SceneError`` for a region or when a joint is missing."""
        if not self.is_joint:
            raise SceneError('the goal is a region, not a joint configuration')
        missing = [j for j in joint_names if j not in self.seed_joints]
        if missing:
            raise SceneError(f'the joint goal misses joints {missing}')
        return np.array([self.seeds[0][self.seed_joints.index(j)] for j in joint_names])

    def error(self, T_base_tool: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
        """(position error in the centre frame [m], rotation-vector error [rad])."""
        T_c = self.center.to_se3()
        p_local = T_c.rotation.T @ (T_base_tool.translation - T_c.translation)
        return p_local, _rotation_error(T_c.rotation, T_base_tool.rotation)

    def contains(self, T_base_tool: pin.SE3, slack: float = 1e-6) -> bool:
        p_err, r_err = self.error(T_base_tool)
        return bool(np.all(np.abs(p_err) <= np.asarray(self.position_tolerance_m) + slack)
                    and np.all(np.abs(r_err) <= np.asarray(self.orientation_tolerance_rad)
                               + slack))


JOINT_TOLERANCE_RAD = 1e-6
"""Largest joint difference [rad] at which a configuration reaches a ``joint`` goal (the
victims end exactly there: their goal is the configuration itself)."""


__all__ = ['GOAL_FORMS', 'GoalRegion', 'JOINT_TOLERANCE_RAD']
