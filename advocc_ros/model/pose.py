"""Rigid poses, number validation and the error type of every scene-like file.

Poses are in the robot base frame, in metres; quaternions are ``[x, y, z, w]`` as in ROS
messages.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pinocchio as pin


class SceneError(ValueError):
    """A malformed scene, goal region or obstacles file; the message names file and field."""


def finite_array(values, where: str, n: int | None = None, positive: bool = False,
                 nonneg: bool = False) -> np.ndarray:
    """``values`` as a float array, or a ``SceneError`` naming ``where``: numbers, finite,
    optionally ``n`` of them and positive / non-negative."""
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise SceneError(f'{where}: expected numbers, got {values!r}') from None
    if n is not None and arr.shape != (n,):
        raise SceneError(f'{where}: expected {n} numbers, got {values!r}')
    if not np.all(np.isfinite(arr)):
        raise SceneError(f'{where}: values must be finite, got {values!r}')
    if positive and not np.all(arr > 0):
        raise SceneError(f'{where}: values must be > 0, got {values!r}')
    if nonneg and not np.all(arr >= 0):
        raise SceneError(f'{where}: values must be >= 0, got {values!r}')
    return arr


@dataclasses.dataclass(frozen=True)
class Pose:
    """Rigid pose: ``position_m`` (3,) and unit quaternion ``quat_xyzw`` (4,)."""

    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @classmethod
    def from_data(cls, data: Any, where: str) -> 'Pose':
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise SceneError(f'{where}: expected a mapping with position/orientation')
        unknown = set(data) - {'position', 'orientation'}
        if unknown:
            raise SceneError(f'{where}: unknown field(s) {sorted(unknown)}')
        pos = finite_array(data.get('position', [0, 0, 0]), f'{where}.position', 3)
        quat = finite_array(data.get('orientation', [0, 0, 0, 1]), f'{where}.orientation', 4)
        norm = np.linalg.norm(quat / np.max(np.abs(quat))) * np.max(np.abs(quat)) \
            if np.any(quat) else 0.0  # scaled: components near 1e308 must not overflow to inf
        if not 1e-6 <= norm < np.inf:
            raise SceneError(f'{where}.orientation: zero or overflowing quaternion '
                             f'{quat.tolist()}')
        return cls(tuple(pos.tolist()), tuple((quat / norm).tolist()))

    @classmethod
    def from_se3(cls, T: pin.SE3) -> 'Pose':
        quat = pin.Quaternion(T.rotation).coeffs()  # x, y, z, w
        return cls(tuple(T.translation.tolist()), tuple(np.asarray(quat).tolist()))

    def to_se3(self) -> pin.SE3:
        x, y, z, w = self.quat_xyzw
        return pin.SE3(pin.Quaternion(w, x, y, z).normalized().matrix(),
                       np.array(self.position_m))

    def to_data(self) -> dict:
        return {'position': [float(v) for v in self.position_m],
                'orientation': [float(v) for v in self.quat_xyzw]}


__all__ = ['Pose', 'SceneError', 'finite_array']
