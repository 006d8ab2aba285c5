"""Figures of one task: heatmap slices with the placed boxes (paper Figs. 4-5), an audit's PSR
curve, and the matplotlib basics the benchmark's figures share (``advocc_ros.bench.figures``)."""

from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use('Agg')  # files only; no display on robots' build machines
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from advocc_ros.fileio import atomic_open  # noqa: E402
from advocc_ros.heatmap import Heatmap  # noqa: E402
from advocc_ros.model.scene import Scene, SceneObject  # noqa: E402

_PLANES = (('XY', 2, (0, 1)), ('XZ', 1, (0, 2)), ('YZ', 0, (1, 2)))
_AXES = 'xyz'


def percent_axes(ax) -> None:
    """A PSR-style axis: 0-100 % with a little room, integer budgets, light grid, legend."""
    ax.set_ylim(-3, 103)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def save_png(fig, out: str | pathlib.Path) -> None:
    """Write the figure as PNG atomically and free it."""
    with atomic_open(out, 'wb') as handle:
        fig.savefig(handle, format='png', dpi=90)
    plt.close(fig)


def plot_heatmap_slices(heatmap: Heatmap, out: str | pathlib.Path, scene: Scene | None = None,
                        obstacles: tuple[SceneObject, ...] | None = None,
                        at_m: list[float] | None = None, numbered: bool = False) -> None:
    """Three orthogonal slices of H through ``at_m`` (default: the peak of H outside the
    robot's fixed base, which every sample occupies). Scene voxels are grey, obstacles red;
    ``numbered`` labels obstacle i (in the given order) with i + 1."""
    grid, H = heatmap.grid, heatmap.values
    if at_m is None:
        masked = H.copy()
        base = grid.index_of(np.zeros(3))
        r = int(np.ceil(0.15 / grid.voxel_m))  # skip the base link: its mass says nothing
        lo, hi = np.maximum(base - r, 0), base + r + 1
        masked[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = 0
        at_idx = np.array(np.unravel_index(int(np.argmax(masked)), H.shape))
    else:
        at_idx = np.clip(grid.index_of(np.asarray(at_m)), 0, np.asarray(grid.shape) - 1)
    at = grid.centers(at_idx)
    positive = H[H > 0]
    norm = LogNorm(vmin=max(positive.min(), positive.max() * 1e-4), vmax=positive.max()) \
        if positive.size else None
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), constrained_layout=True)
    for ax, (name, normal, (a, b)) in zip(axes, _PLANES):
        sl = [slice(None)] * 3
        sl[normal] = at_idx[normal]
        plane = H[tuple(sl)]
        blocked = ~heatmap.free[tuple(sl)]
        extent = (grid.origin_m[a], grid.upper_m[a], grid.origin_m[b], grid.upper_m[b])
        img = ax.imshow(np.ma.masked_less_equal(plane.T, 0), origin='lower', extent=extent,
                        cmap='inferno', norm=norm, interpolation='nearest')
        ax.imshow(np.ma.masked_equal(blocked.T.astype(float), 0), origin='lower', extent=extent,
                  cmap='Greys', vmin=0, vmax=1.5, alpha=0.8, interpolation='nearest')
        for number, obj in enumerate(obstacles or (), start=1):
            for shape in obj.shapes:
                c, size = np.asarray(shape.pose.position_m), np.asarray(shape.dims)
                if abs(c[normal] - at[normal]) <= size[normal] / 2 + grid.voxel_m:
                    ax.add_patch(Rectangle((c[a] - size[a] / 2, c[b] - size[b] / 2), size[a],
                                           size[b], fill=False, ec='red', lw=2))
                else:
                    ax.plot(c[a], c[b], 's', mfc='none', mec='red', ms=6)
                if numbered:
                    ax.annotate(str(number), (c[a] + size[a] / 2, c[b] + size[b] / 2),
                                color='red', fontsize=10, fontweight='bold',
                                xytext=(2, 2), textcoords='offset points',
                                bbox=dict(boxstyle='round,pad=0.1', fc='white', alpha=0.6,
                                          lw=0))
        if scene is not None and scene.goal is not None:
            g = np.asarray(scene.goal.center.position_m)
            ax.plot(g[a], g[b], '*', color='cyan', ms=14, label='goal region centre')
        ax.set_title(f'{name} slice at {_AXES[normal]} = {at[normal]:.2f} m')
        ax.set_xlabel(f'{_AXES[a]} [m]')
        ax.set_ylabel(f'{_AXES[b]} [m]')
    if norm is not None:
        fig.colorbar(img, ax=axes, shrink=0.8, label='H (accumulated weight)')
    title = f'kinematic occupancy heatmap: {heatmap.meta.get("valid_samples")} samples'
    if heatmap.meta.get('scene_name'):
        title += f', scene {heatmap.meta["scene_name"]}'
    fig.suptitle(title)
    save_png(fig, out)


def _evaluated(curve: list[float | None]) -> tuple[list[int], list[float]]:
    """The evaluated m of ``curve`` and their values [%]."""
    m = [i for i, v in enumerate(curve) if v is not None]
    return m, [100 * curve[i] for i in m]


def _join(ax, curve: list[float | None], color, ls: str) -> None:
    """Consecutive evaluated points of ``curve`` joined: ``ls`` between adjacent m, dotted
    across a gap."""
    m, y = _evaluated(curve)
    for (m0, y0), (m1, y1) in zip(zip(m, y), zip(m[1:], y[1:])):
        ax.plot([m0, m1], [y0, y1], color=color, ls=ls if m1 == m0 + 1 else ':')


def plot_audit_psr(psr: dict[str, list[float | None]], goal_valid: list[float | None],
                   out: str | pathlib.Path, title: str = '') -> None:
    """:func:`audit_psr_figure` written as a PNG to ``out``."""
    save_png(audit_psr_figure(psr, goal_valid, title), out)


def audit_psr_figure(psr: dict[str, list[float | None]], goal_valid: list[float | None],
                     title: str = ''):
    """An audit's curves: PSR [%] of each planner against the budget m (lists indexed by m,
    None where not evaluated), and the share of goal poses the boxes leave valid (dashed).
    Points at adjacent m are joined by a solid line, points across unevaluated m by a dotted
    one: the curve between them was not measured. Returns the matplotlib figure."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2), constrained_layout=True)
    for planner, curve in psr.items():
        line, = ax.plot(*_evaluated(curve), marker='o', ls='none', label=planner)
        _join(ax, curve, color=line.get_color(), ls='-')
    ax.plot(*_evaluated(goal_valid), ls='none', marker='.', color='gray',
            label='goal poses valid')
    _join(ax, goal_valid, color='gray', ls='--')
    for level in (80, 60, 40, 20):
        ax.axhline(level, color='black', lw=0.5, alpha=0.25)
    ax.set_xlabel('boxes m')
    ax.set_ylabel('PSR, goal poses valid [%]')
    percent_axes(ax)
    if title:
        ax.set_title(title)
    return fig
