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


def campaign_figure(cases: list[dict], keys: list[str], title: str = ""):
    """theta(t) of every case of a campaign on a grid over (up to) two swept parameters.

    ``cases``: dicts with the swept values, ``status``, ``series`` (time series)
    and ``last`` (the last snapshot, or None); ``keys``: the swept parameters.
    Each panel carries the case's last shape coloured by psi.
    """
    row_key = keys[0] if len(keys) >= 2 else None
    col_key = keys[-1] if keys else None
    rows = sorted({c[row_key] for c in cases}) if row_key else [None]
    cols = sorted({c[col_key] for c in cases}) if col_key else [None]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.2 * len(cols) + 0.8, 2.4 * len(rows) + 0.8),
                             squeeze=False, constrained_layout=True)
    for ax in axes.flat:
        ax.set_visible(False)
    names = {"shear_rate": "S", "psi_bar": r"$\bar\psi$", "excess_length": r"$\Delta$", "B2": r"$B_2$"}
    for c in cases:
        i = rows.index(c[row_key]) if row_key else 0
        j = cols.index(c[col_key]) if col_key else 0
        ax = axes[i, j]
        ax.set_visible(True)
        series = c["series"]
        ax.plot(series["t"], series["theta"], color="k", lw=0.8)
        label = ", ".join(f"{names.get(k, k)} = {c[k]:g}" for k in keys)
        colour = {"finished": "k", "failed": "tab:red"}.get(c["status"], "tab:orange")
        ax.set_title(label + ("" if c["status"] == "finished" else f" ({c['status']})"), fontsize=9,
                     color=colour)
        if i == len(rows) - 1:
            ax.set_xlabel("t")
        if j == 0:
            ax.set_ylabel(r"$\theta$ [rad]")
        last = c.get("last")
        if last is not None:
            inset = ax.inset_axes([0.6, 0.04, 0.38, 0.45])
            shape_strip(inset, {k: v[None] for k, v in last.items()}, [0], label_times=False)
    if title:
        fig.suptitle(title)
    return fig
