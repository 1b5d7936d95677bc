"""Figures of one case (matplotlib, no display needed).

:func:`case_figure` draws, from the time series and snapshots of a case file:
the inclination theta(t), both energies, the tension (min / mean / max), the
phase velocities V_psi, V_L and their sum, and a strip of shapes coloured by psi.
"""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

PSI_CMAP = "coolwarm"      # blue: hard phase (psi = 0), red: soft phase (psi = 1)


def shape_strip(ax, snapshots: dict, indices, spacing: float = 1.3, label_times: bool = True):
    """Draw the shapes of the chosen snapshots side by side, coloured by psi."""
    collections = []
    for k, i in enumerate(indices):
        x, y, psi = snapshots["x"][i], snapshots["y"][i], snapshots["psi"][i]
        cx, cy = x.mean(), y.mean()
        xs = np.r_[x, x[0]] - cx + k * spacing
        ys = np.r_[y, y[0]] - cy
        points = np.stack([xs, ys], axis=1)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        lc = LineCollection(segments, cmap=PSI_CMAP, linewidth=3)
        lc.set_array(0.5 * (np.r_[psi, psi[0]][:-1] + np.r_[psi, psi[0]][1:]))
        lc.set_clim(0.0, 1.0)
        ax.add_collection(lc)
        collections.append(lc)
        if label_times:
            ax.text(k * spacing, -0.62, f"t = {snapshots['t'][i]:.3g}", ha="center", fontsize=9)
    ax.set_xlim(-0.7, (len(indices) - 1) * spacing + 0.7)
    ax.set_ylim(-0.75, 0.6)
    ax.set_aspect("equal")
    ax.axis("off")
    return collections[-1] if collections else None


def case_figure(series: dict, snapshots: dict, title: str = "", n_shapes: int = 8):
    """A one-page summary of a case."""
    t = series["t"]
    fig = plt.figure(figsize=(12, 9), constrained_layout=True)
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 1.1])
    ax = fig.add_subplot(grid[0, 0])
    ax.plot(t, series["theta"], color="k", lw=1)
    ax.set_xlabel("t")
    ax.set_ylabel(r"inclination $\theta$ [rad]")

    ax = fig.add_subplot(grid[0, 1])
    ax.plot(t, series["E_bending"], label=r"$E_b$")
    ax.plot(t, series["E_phase"], label=r"$E_\psi$")
    ax.set_xlabel("t")
    ax.set_ylabel("energy")
    ax.legend(frameon=False)

    ax = fig.add_subplot(grid[1, 0])
    ax.fill_between(t, series["tension_min"], series["tension_max"], alpha=0.3, label="min - max")
    ax.plot(t, series["tension_mean"], label="mean")
    ax.set_xlabel("t")
    ax.set_ylabel(r"tension $\Lambda$")
    ax.legend(frameon=False)

    ax = fig.add_subplot(grid[1, 1])
    ax.plot(t, series["V_psi"], label=r"$V_\psi$ (phase vs material)")
    ax.plot(t, series["V_L"], label=r"$V_L$ (material vs long axis)")
    ax.plot(t, series["V_psi"] + series["V_L"], color="k", lw=1.2, label=r"$V_\psi + V_L$ (phase, lab)")
    ax.set_xlabel("t")
    ax.set_ylabel("velocity along the membrane")
    ax.legend(frameon=False, fontsize=8)

    ax = fig.add_subplot(grid[2, :])
    n = len(snapshots["t"])
    if n:
        indices = np.unique(np.linspace(0, n - 1, min(n_shapes, n)).round().astype(int))
        mappable = shape_strip(ax, snapshots, indices)
        fig.colorbar(mappable, ax=ax, shrink=0.7, label=r"$\psi$ (1 = soft)")
    if title:
        fig.suptitle(title)
    return fig


def case_title(attrs) -> str:
    get = attrs.get
    return (f"S = {get('physics.shear_rate'):g}, $\\bar\\psi$ = {get('physics.psi_bar'):g}, "
            f"$\\Delta$ = {get('physics.excess_length'):g}, $B_2/B_1$ = "
            f"{get('physics.B2') / get('physics.B1'):g}, N = {get('numerics.N')}, dt = {get('numerics.dt'):g}")
