"""Figures of one case (matplotlib, no display needed).

:func:`case_figure` draws, from the time series and snapshots of a case file:
the inclination theta(t), both energies, the tension (min / mean / max), the
phase velocities V_psi, V_L and their sum, a strip of shapes coloured by psi
and kymographs of tension and curvature in the material frame;
:func:`shape_sequences`, :func:`animation` and :func:`campaign_figure` draw
shapes and series of several cases. Diagrams over a campaign's parameters are
in :mod:`hpcves.reports.diagrams`.
"""
from __future__ import annotations

import math

import matplotlib
import matplotlib.cm
import matplotlib.colors
import matplotlib.lines
import matplotlib.ticker
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from hpcves.model.params import dealias_label
from hpcves.reports.diagrams import SHORT_NAMES

PSI_CMAP = "coolwarm"      # blue: hard phase (psi = 0), red: soft phase (psi = 1)


def shape_strip(ax, snapshots: dict, indices, spacing: float = 1.3, label_times: bool = True,
                physics=None, colour_width: float = 3.0):
    """Draw the shapes of the chosen snapshots side by side, coloured by psi; with the case's
    ``physics``, the streamlines of the flow around each (:func:`streamlines`) behind it."""
    collections = []
    for k, i in enumerate(indices):
        x, y, psi = snapshots["x"][i], snapshots["y"][i], snapshots["psi"][i]
        cx, cy = x.mean(), y.mean()
        if physics is not None and "velocity_x" in snapshots:
            streamlines(ax, {name: snapshots[name][i] for name in STREAMLINE_FIELDS}, physics,
                        offset=complex(k * spacing - cx, -cy), half_width=0.5 * spacing)
        xs = np.r_[x, x[0]] - cx + k * spacing
        ys = np.r_[y, y[0]] - cy
        points = np.stack([xs, ys], axis=1)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        lc = LineCollection(segments, cmap=PSI_CMAP, linewidth=colour_width, zorder=3)
        lc.set_array(0.5 * (np.r_[psi, psi[0]][:-1] + np.r_[psi, psi[0]][1:]))
        lc.set_clim(0.0, 1.0)
        ax.add_collection(lc)
        collections.append(lc)
        if label_times:
            ax.text(k * spacing, -0.62, f"t = {snapshots['t'][i]:.3g}", ha="center", fontsize=9)
    ax.set_xlim(-0.5 * spacing, (len(indices) - 0.5) * spacing)
    ax.set_ylim(-0.75, 0.6)
    ax.set_aspect("equal")
    ax.axis("off")
    return collections[-1] if collections else None


#: what :func:`streamlines` reads of a snapshot
STREAMLINE_FIELDS = ("x", "y", "psi", "tension", "curvature", "velocity_x", "velocity_y")


def streamlines(ax, snapshot: dict, physics, offset: complex = 0.0, half_width: float = 0.65,
                half_height: float = 0.55, points: int = 56, density: float = 0.7) -> None:
    """Streamlines of the flow around one snapshot, inside and outside (hpcves/model/flowfield.py), in
    the frame moving with the vesicle: the lab-frame velocity less the membrane's mean velocity.
    The snapshot's point z is drawn at z + ``offset``."""
    from hpcves.model.flowfield import around_snapshot

    x, y = np.asarray(snapshot["x"]), np.asarray(snapshot["y"])
    centre = complex(x.mean(), y.mean())
    gx = np.linspace(-half_width, half_width, points)
    gy = np.linspace(-half_height, half_height, int(points * half_height / half_width))
    grid = centre + gx[None, :] + 1j * gy[:, None]
    u = around_snapshot(snapshot, physics, grid)
    u -= np.mean(np.asarray(snapshot["velocity_x"]) + 1j * np.asarray(snapshot["velocity_y"]))
    ax.streamplot(gx + (centre + offset).real, gy + (centre + offset).imag, u.real, u.imag, density=density,
                  color="0.55", linewidth=0.6, arrowsize=0.6, zorder=1, broken_streamlines=True)


#: snapshots per fastest period below which a kymograph is coarse (and below 2: aliased)
SMOOTH_SNAPSHOTS_PER_PERIOD = 8


def fastest_period(tank_treading_velocity, length: float, period: float = math.nan) -> float:
    """The shortest time on which the material-frame fields repeat: the oscillation ``period``,
    or half the time a material point takes round the membrane, L / (2 |<V>|) (a shape's two
    tips pass it twice a circuit), whichever is shorter (NaN if neither is known)."""
    speed = abs(float(np.nanmean(np.asarray(tank_treading_velocity, dtype=float))))
    circuit = 0.5 * length / speed if speed > 0 else math.nan
    known = [p for p in (period, circuit) if np.isfinite(p) and p > 0]
    return min(known) if known else math.nan


def cadence_warning(snapshot_interval: float, fastest: float) -> str:
    """"" when the snapshots resolve the fastest period (at least SMOOTH_SNAPSHOTS_PER_PERIOD in it),
    else what is wrong and the run.snapshot_interval that would do."""
    if not (np.isfinite(fastest) and np.isfinite(snapshot_interval)) or snapshot_interval <= 0:
        return ""
    per_period = fastest / snapshot_interval
    if per_period >= SMOOTH_SNAPSHOTS_PER_PERIOD:
        return ""
    what = "aliased" if per_period < 2 else "coarse"
    return (f"{what}: snapshots every {snapshot_interval:.3g}, {per_period:.2g} per period {fastest:.3g};\n"
            f"run.snapshot_interval <= {fastest / SMOOTH_SNAPSHOTS_PER_PERIOD:.2g} resolves it")


def settled_window(t: np.ndarray, t_settle: float = math.nan) -> np.ndarray:
    """The samples from ``t_settle`` on (all of them when it is unknown or leaves fewer than 10)."""
    t = np.asarray(t)
    if not np.isfinite(t_settle):
        return np.ones(t.size, dtype=bool)
    window = t >= t_settle
    return window if np.count_nonzero(window) >= 10 else np.ones(t.size, dtype=bool)


def case_figure(series: dict, snapshots: dict, title: str = "", n_shapes: int = 8, kymographs: bool = False,
                *, t_settle: float = math.nan, period: float = math.nan, physics=None, subtitle: str = ""):
    """A one-page summary of a case: theta, the energies, the tension (min / mean / max) and the
    phase velocities over the settled window (from ``t_settle``; an inset shows theta's whole
    record), shapes coloured by psi over the last ``period`` (with ``physics``: and the
    streamlines around them), and with ``kymographs`` tension and curvature over (alpha, t)."""
    t = np.asarray(series["t"])
    window = settled_window(t, t_settle)
    settled = not np.all(window)
    tw = t[window]
    rows = 4 if kymographs and len(snapshots["t"]) >= 2 else 3
    ratios = [1, 1, 0.6, 1.1][:rows]            # the shapes' strip is about a tenth as high as it is wide
    fig = Figure(figsize=(12, 3.1 * sum(ratios) + 0.6), constrained_layout=True)
    grid = fig.add_gridspec(rows, 2, height_ratios=ratios)
    xlabel = f"t (settled from t = {tw[0]:.3g})" if settled else "t"

    ax = fig.add_subplot(grid[0, 0])
    shown, label = _about_mean(np.asarray(series["theta"])[window], r"$\theta$", " [rad]")
    ax.plot(tw, shown, color="k", lw=1)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("inclination " + label)
    if settled and tw[0] - t[0] > 0.1 * (t[-1] - t[0]):    # the whole record, the window shaded, above the data
        low, high = ax.get_ylim()
        ax.set_ylim(low, high + 0.7 * (high - low))
        inset = ax.inset_axes([0.7, 0.64, 0.28, 0.3])
        inset.plot(t, series["theta"], color="0.3", lw=0.7)
        inset.axvspan(tw[0], tw[-1], color="tab:green", alpha=0.2, lw=0)
        inset.tick_params(labelsize=7)
        inset.set_title("whole run", fontsize=7, pad=2)

    centroid = np.asarray(series["centroid"]) if "centroid" in series else None
    parts = 3 if centroid is not None and centroid.ndim == 2 and len(centroid) == len(t) else 2
    energy = grid[0, 1].subgridspec(parts, 1, hspace=0.0)   # each on its own axes: none hides another
    ax_b = fig.add_subplot(energy[0])
    ax_p = fig.add_subplot(energy[1], sharex=ax_b)
    for axis, key, name, colour in ((ax_b, "E_bending", "$E_b$", "tab:blue"),
                                    (ax_p, "E_phase", r"$E_\psi$", "tab:orange")):
        shown, label = _about_mean(np.asarray(series[key])[window], name)
        axis.plot(tw, shown, color=colour, lw=1)
        axis.set_ylabel(label, color=colour, fontsize=9)
        axis.tick_params(labelsize=8)
    ax_b.tick_params(labelbottom=False)
    ax_b.set_title("bending and line energy" + (", centroid" if parts == 3 else ""), fontsize=9)
    last = ax_p
    if parts == 3:                   # the centroid (x_c, y_c): it stays put in simple shear, up to numerics
        ax_p.tick_params(labelbottom=False)
        last = fig.add_subplot(energy[2], sharex=ax_b)
        for k, (name, colour) in enumerate((("$x_c$", "tab:green"), ("$y_c$", "tab:purple"))):
            last.plot(tw, centroid[window, k], color=colour, lw=1, label=name)
        last.set_ylabel("centroid", fontsize=9)
        last.tick_params(labelsize=8)
        last.legend(frameon=False, fontsize=8, ncol=2, loc="best")
    last.set_xlabel(xlabel)

    ax = fig.add_subplot(grid[1, 0])
    ax.fill_between(tw, np.asarray(series["tension_min"])[window], np.asarray(series["tension_max"])[window],
                    alpha=0.3, label="min - max")
    ax.plot(tw, np.asarray(series["tension_mean"])[window], label="mean")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(r"tension $\Lambda$")
    ax.legend(frameon=False, fontsize=9, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2)

    ax = fig.add_subplot(grid[1, 1])
    v_psi, v_l = np.asarray(series["V_psi"])[window], np.asarray(series["V_L"])[window]
    ax.plot(tw, v_psi + v_l, color="k", lw=2.4, alpha=0.35, label=r"$V_\psi + V_L$ (phase, lab)")
    ax.plot(tw, v_psi, color="tab:blue", lw=1.2, label=r"$V_\psi$ (phase vs material)")
    ax.plot(tw, v_l, color="tab:orange", lw=1.2, ls="--", label=r"$V_L$ (material vs long axis)")
    off_scale = _clip_outliers(ax, np.concatenate([v_psi + v_l, v_psi, v_l]))
    if off_scale:
        ax.text(0.99, 0.02, off_scale, transform=ax.transAxes, ha="right", va="bottom", fontsize=8,
                color="tab:red")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("velocity along the membrane")
    ax.legend(frameon=False, fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2)

    ax = fig.add_subplot(grid[2, :])
    snap_t = np.asarray(snapshots["t"])
    n = snap_t.size
    if n:
        indices = _shape_indices(snap_t, tw[0] if settled else snap_t[0], period, n_shapes)
        mappable = shape_strip(ax, snapshots, indices, physics=physics)
        fig.colorbar(mappable, ax=ax, fraction=0.02, pad=0.01, aspect=12, label=r"$\psi$ (1 = soft)")
        if physics is not None and "velocity_x" in snapshots:
            ax.set_title("streamlines in the frame moving with the vesicle", fontsize=9)
    if kymographs and n >= 2:
        chosen = snap_t >= (tw[0] if settled else snap_t[0])
        if np.count_nonzero(chosen) < 2:
            chosen = np.ones(n, dtype=bool)
        window_snaps = {k: np.asarray(v)[chosen] for k, v in snapshots.items()}
        interval = float(np.median(np.diff(snap_t))) if n >= 2 else math.nan
        z = np.asarray(snapshots["x"][-1]) + 1j * np.asarray(snapshots["y"][-1])
        length = float(np.sum(np.abs(np.diff(np.r_[z, z[:1]]))))
        warning = cadence_warning(interval, fastest_period(np.asarray(series["tank_treading_velocity"])[window],
                                                           length, period))
        for k, (name, label) in enumerate((("tension", r"tension $\Lambda(\alpha, t)$"),
                                           ("curvature", r"curvature $H(\alpha, t)$"))):
            ax = fig.add_subplot(grid[3, k])
            kymograph(ax, fig, window_snaps, name, label)
            if warning:
                ax.set_title(warning, fontsize=8, color="tab:red")
    if title:
        fig.suptitle(title + (f"\n{subtitle}" if subtitle else ""), fontsize=11)
    return fig


def _clip_outliers(ax, values: np.ndarray, coverage: float = 99.0) -> str:
    """Scale ``ax``'s y axis to the central ``coverage`` % of ``values`` (with a margin) when a few
    samples lie far outside it, e.g. the phase velocity of a pattern whose position is undefined
    for an instant; what was left off the scale ("" when nothing was)."""
    finite = values[np.isfinite(values)]
    if finite.size < 10:
        return ""
    low, high = np.percentile(finite, [(100 - coverage) / 2, (100 + coverage) / 2])
    margin = 0.25 * (high - low) or 0.25 * max(abs(low), abs(high), 1e-12)
    low, high = low - margin, high + margin
    outside = np.count_nonzero((finite < low) | (finite > high))
    if outside == 0:
        return ""
    ax.set_ylim(low, high)
    extreme = finite[np.argmax(np.abs(finite))]
    return f"{outside} of {finite.size} values off the scale (extreme {extreme:.3g})"


def _about_mean(values: np.ndarray, name: str, unit: str = "") -> tuple[np.ndarray, str]:
    """(what to plot, its axis label): the values, or where they vary by less than 1e-3 of their
    mean, their deviation from it, named so ("theta - 0.5121 [rad]"): no offset notation."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return values, name + unit
    mean = float(np.mean(finite))
    if mean == 0 or np.ptp(finite) >= 1e-3 * abs(mean):
        return values, name + unit
    return values - mean, f"{name} $-$ {mean:.6g}{unit}"


def _shape_indices(snap_t: np.ndarray, start: float, period: float, n_shapes: int) -> np.ndarray:
    """Snapshots to draw: over the last period when it holds at least 4 of them, else spread over
    the snapshots from ``start`` on."""
    last = snap_t[-1]
    if np.isfinite(period) and np.count_nonzero(snap_t >= last - period) >= 4:
        candidates = np.flatnonzero(snap_t >= last - period)
    else:
        candidates = np.flatnonzero(snap_t >= start)
        if candidates.size == 0:
            candidates = np.arange(snap_t.size)
    picks = np.linspace(0, candidates.size - 1, min(n_shapes, candidates.size)).round().astype(int)
    return candidates[np.unique(picks)]


def material_frame(snapshots: dict, name: str, n_alpha: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """(alpha grid, field(t, alpha)): a snapshot field as a function of the material label.

    Node j of a snapshot sits at arclength fraction j/N; the material there has
    label alpha = (j/N - shift) mod 1 (the shift a(t) is recorded with every
    snapshot). Each snapshot is interpolated periodically onto a fixed alpha grid.
    """
    values = np.asarray(snapshots[name])
    N = values.shape[1]
    alpha = np.arange(n_alpha) / n_alpha
    out = np.empty((values.shape[0], n_alpha))
    for i, (row, shift) in enumerate(zip(values, snapshots["shift"])):
        labels = (np.arange(N) / N - shift) % 1.0
        out[i] = np.interp(alpha, labels, row, period=1.0)
    return alpha, out


def kymograph(ax, fig, snapshots: dict, name: str, label: str) -> None:
    """field(alpha, t) as an image: time along x, the material label along y."""
    alpha, values = material_frame(snapshots, name)
    t = np.asarray(snapshots["t"])
    low, high = np.nanpercentile(values, [1, 99])
    image = ax.pcolormesh(t, alpha, values.T, shading="nearest", cmap="viridis", vmin=low, vmax=high,
                          rasterized=True)
    fig.colorbar(image, ax=ax, label=label)
    ax.set_xlabel("t")
    ax.set_ylabel(r"material label $\alpha$")

def case_title(attrs) -> str:
    get = attrs.get
    return (f"S = {get('physics.shear_rate'):g}, $\\bar\\psi$ = {get('physics.psi_bar'):g}, "
            f"$\\Delta$ = {get('physics.excess_length'):g}, $B_2/B_1$ = "
            f"{get('physics.B2') / get('physics.B1'):g}, "
            + (f"$\\lambda$ = {get('physics.viscosity_ratio'):g}, "
               if get('physics.viscosity_ratio', 1.0) != 1.0 else "")
            + (f"N = auto ({get('numerics.N')}-{get('numerics.N_max')})" if get('numerics.N_max', 0) else
               f"N = {get('numerics.N')}")
            + dealias_label(get('numerics.dealias', 1.0))
            + ", " + step_label(attrs)
            + _start_label(attrs))


def _start_label(attrs) -> str:
    """", smoothed start", ", domains phase": how a case started where it is not the published start (files
    from before the options: "")."""
    def text(key, default):
        value = attrs.get(key, default)
        return value.decode() if isinstance(value, bytes) else str(value)
    shape, phase = text("physics.initial_shape", "ellipse"), text("physics.initial_phase", "published")
    return (("" if shape == "ellipse" else f", {shape} start") + ("" if phase == "published" else f", {phase} phase"))


def step_label(attrs) -> str:
    """"dt = 0.0005" for a fixed step, "rtol = 0.001" for an adaptive one (case attributes)."""
    rtol = attrs.get("numerics.rtol")
    if rtol is not None and not (isinstance(rtol, float) and np.isnan(rtol)):
        return f"rtol = {float(rtol):g}"
    return f"dt = {attrs.get('numerics.dt'):g}"


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
    fig = Figure(figsize=(3.2 * len(cols) + 0.8, 2.4 * len(rows) + 0.8), constrained_layout=True)
    axes = fig.subplots(len(rows), len(cols), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    names = SHORT_NAMES
    for c in cases:
        i = rows.index(c[row_key]) if row_key else 0
        j = cols.index(c[col_key]) if col_key else 0
        ax = axes[i, j]
        ax.set_visible(True)
        series = c["series"]
        ax.plot(series["t"], series["theta"], color="k", lw=0.8)
        label = ", ".join(f"{names.get(k, k)} = {c[k]:g}" for k in keys)
        colour = {"finished": "k", "failed": "tab:red", "model limit": "tab:purple"}.get(c["status"], "tab:orange")
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


@matplotlib.rc_context({"font.size": 12})
def shape_sequences(rows: list[tuple], title: str = "", n_shapes: int = 6, streamlines_on: bool = True):
    """Rows of shapes coloured by psi, one row per case, over its last period (else its settled
    window), with the streamlines around each; ``rows``: (label, snapshots, physics, t_settle,
    period) per case. One colour bar for all."""
    fig = Figure(figsize=(2.1 * n_shapes + 1.6, 2.0 * len(rows) + 0.6), constrained_layout=True)
    axes = fig.subplots(len(rows), 1, squeeze=False)
    mappable = None
    for ax, (label, snapshots, physics, t_settle, period) in zip(axes[:, 0], rows):
        snap_t = np.asarray(snapshots["t"])
        start = t_settle if np.isfinite(t_settle) else snap_t[0]
        indices = _shape_indices(snap_t, start, period, n_shapes)
        mappable = shape_strip(ax, snapshots, indices, physics=physics if streamlines_on else None) or mappable
        ax.set_xlim(-0.65, (n_shapes - 0.5) * 1.3)          # every row on the same scale, from the left
        ax.set_title(label, fontsize=12, loc="left")
    if mappable is not None:
        fig.colorbar(mappable, ax=axes[:, 0].tolist(), shrink=0.8, label=r"$\psi$ (1 = soft)")
    if title:
        fig.suptitle(title)
    return fig


def animation(series: dict, snapshots: dict, physics=None, title: str = "", extent: float = 0.75):
    """(figure, matplotlib FuncAnimation) of a case, one frame per snapshot: the shape coloured by
    psi with the streamlines around it (with ``physics``) beside theta(t) up to the frame's time."""
    from matplotlib.animation import FuncAnimation

    fig = Figure(figsize=(11, 4.6), constrained_layout=True)
    grid = fig.add_gridspec(1, 2, width_ratios=[1.25, 1])
    shape_ax, theta_ax = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])
    t, theta = np.asarray(series["t"]), np.asarray(series["theta"])
    theta_ax.plot(t, theta, color="0.8", lw=1)
    trace, = theta_ax.plot([], [], color="k", lw=1.2)
    marker, = theta_ax.plot([], [], "o", color="tab:red")
    theta_ax.set_xlabel("t")
    theta_ax.set_ylabel(r"inclination $\theta$ [rad]")
    snap_t = np.asarray(snapshots["t"])
    norm = matplotlib.colors.Normalize(0.0, 1.0)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=PSI_CMAP), ax=shape_ax, shrink=0.8,
                 label=r"$\psi$ (1 = soft)")
    if title:
        fig.suptitle(title)

    def draw(i):
        shape_ax.clear()
        shape_strip(shape_ax, snapshots, [i], spacing=2 * extent, label_times=False,
                    physics=physics)
        shape_ax.set_xlim(-extent, extent)
        shape_ax.set_ylim(-0.62 * extent / 0.75, 0.62 * extent / 0.75)
        shape_ax.set_title(f"t = {snap_t[i]:.4g}", fontsize=11)
        upto = t <= snap_t[i]
        trace.set_data(t[upto], theta[upto])
        if np.any(upto):
            marker.set_data([t[upto][-1]], [theta[upto][-1]])
        return ()

    return fig, FuncAnimation(fig, draw, frames=snap_t.size, blit=False)
