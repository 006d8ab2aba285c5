"""The offline phase's parameters (``HeatmapConfig``) and those a heatmap file records for its
weights (``weight_config``): plain data, apart from the build's compiled kernels, so what only
reads or passes them on (the attack's settings, the nodes) loads no compiler."""

from __future__ import annotations

import dataclasses

import numpy as np

from advocc_ros.heatmap.store import DEFAULT_LUT_PITCH_FRACTION, Heatmap, HeatmapError


@dataclasses.dataclass(frozen=True)
class HeatmapConfig:
    """Offline parameters, defaults from the paper (§V-A) and docs/design.md."""

    samples: int = 15_000
    """N_off: number of *valid* configurations."""
    voxel_m: float = 0.02
    """delta: voxel edge [m]."""
    kappa: float = 0.01
    """Manipulability saturation: s_man = m / (m + kappa)."""
    d_safe_m: float = 0.1
    """Clearance normalisation: s_clr = min(d_clr / d_safe, 1) [m]."""
    gamma_man: float = 1.0
    gamma_clr: float = 1.0
    margin_m: float = 0.1
    """Padding around the robot's swept-volume bounding box [m]."""
    robot_only: bool = False
    """Ignore the scene offline (E empty); the online phase masks the current scene."""
    lut_pitch_fraction: float = DEFAULT_LUT_PITCH_FRACTION
    """Link look-up-table pitch as a fraction of the voxel edge."""

    def __post_init__(self):
        checks = {'samples': self.samples >= 1, 'voxel_m': 0.002 <= self.voxel_m <= 0.5,
                  'kappa': self.kappa > 0, 'd_safe_m': self.d_safe_m > 0,
                  'gamma_man': self.gamma_man >= 0, 'gamma_clr': self.gamma_clr >= 0,
                  'margin_m': self.margin_m >= 0,
                  'lut_pitch_fraction': 0 < self.lut_pitch_fraction <= 1}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or not np.isfinite(float(value)):
                raise ValueError(f'heatmap parameter {name}={value!r} is out of range')


_WEIGHT_PARAMS = ('kappa', 'd_safe_m', 'gamma_man', 'gamma_clr')


def weight_config(heatmap: Heatmap) -> HeatmapConfig:
    """The w(q) parameters ``heatmap`` was built with, so that an attack weighs configurations
    as the heatmap did (a file that records none was built with the defaults)."""
    params = heatmap.meta.get('params')
    params = params if isinstance(params, dict) else {}
    try:
        return HeatmapConfig(**{k: float(params[k]) for k in _WEIGHT_PARAMS if k in params})
    except (TypeError, ValueError) as exc:
        raise HeatmapError(f'heatmap params: {exc}') from None


__all__ = ['HeatmapConfig', 'weight_config']
