"""Figures of one case (matplotlib, no display needed).

:func:`case_figure` draws, from the time series and snapshots of a case file:
the inclination theta(t), both energies, the tension (min / mean / max), the
phase velocities V_psi, V_L and their sum, a strip of shapes coloured by psi
and kymographs of tension and curvature in the material frame.
:func:`phase_diagram` and :func:`period_figure` draw a campaign's regimes.
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

from hpcves.analysis import accuracy
from hpcves.model.params import PARAMETER_NAMES, dealias_label

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


REGIME_STYLE = {            # colour, marker, label
    "TT": ("tab:blue", "o", "tank-treading"),
    "PT": ("tab:orange", "s", "phase-treading"),
    "TU": ("tab:red", "^", "tumbling"),
    "undecided": ("0.55", "x", "undecided"),
    "model limit": ("tab:purple", "D", r"model limit ($\psi$ left [0, 1])"),
    "failed": ("k", "X", "failed"),
}
SHORT_NAMES = {key: name.symbol for key, name in PARAMETER_NAMES.items()}


def parameter_text(fixed: dict) -> str:
    """``$\\bar\\psi$ = 0.48, $B_2$ = 0.1``: fixed parameters in a figure's title."""
    return ", ".join(f"{SHORT_NAMES.get(k, k)} = {v:g}" for k, v in fixed.items())


AXIS_LABELS = {key: name.axis for key, name in PARAMETER_NAMES.items()}


#: parameters whose effect goes with their logarithm: on a log axis wherever they are positive
LOG_KEYS = ("shear_rate", "viscosity_ratio")


def _log_scale(values, key: str = "") -> bool:
    values = np.asarray(sorted(set(values)), dtype=float)
    if values.size >= 2 and values.min() > 0 and key in LOG_KEYS:
        return True
    return values.size >= 3 and values.min() > 0 and values.max() / values.min() >= 20


@matplotlib.rc_context({"font.size": 14})          # readable in a talk; the caller's settings are restored
def phase_diagram(rows: list[dict], x_key: str, y_key: str, title: str = "", annotate_periods: bool = True,
                  regions=None, log_keys=None):
    """Regimes over two swept parameters, every case drawn: one marker per case, coloured by regime;
    undecided cases are grey crosses, model-limit ones purple diamonds, failed ones black crosses;
    PT/TU points carry their period; the legend beside the axes. Shaded: the ``regions`` that the
    cases decide (default: :func:`decided_regions`; a refinement passes its cells), never beyond them.
    ``log_keys``: the parameters drawn on a log axis (default: the shear rate and the viscosity
    ratio, and any other swept over a factor of 20 or more)."""
    fig = Figure(figsize=(10, 6), constrained_layout=True)
    ax = fig.subplots()
    size = 140 if len(rows) <= 60 else 50                      # a refined map has hundreds of points
    for regime, (colour, marker, label) in REGIME_STYLE.items():
        chosen = [r for r in rows if r["regime"] == regime]
        if not chosen:
            continue
        ax.scatter([r[x_key] for r in chosen], [r[y_key] for r in chosen], s=size, c=colour, marker=marker,
                   label=f"{label} ({len(chosen)})", edgecolors="k" if marker not in "xX" else None,
                   linewidths=0.6,
                   zorder=3)
        if annotate_periods and regime in ("PT", "TU"):
            for r in chosen:
                if np.isfinite(r["period"]):
                    ax.annotate(f"{r['period']:.3g}", (r[x_key], r[y_key]), textcoords="offset points",
                                xytext=(0, 9), ha="center", fontsize=9)
    for axis, key in ((ax.xaxis, x_key), (ax.yaxis, y_key)):
        values = sorted({r[key] for r in rows})
        if (key in log_keys) if log_keys is not None else _log_scale(values, key):
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
            if log_keys is None and len(values) <= MAX_SWEEP_TICKS:   # ticks at the swept values
                axis.set_ticks(values, [f"{v:g}" for v in values])
            else:
                plain_log_ticks(axis)
            axis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(AXIS_LABELS.get(y_key, y_key))
    ax.grid(alpha=0.3)
    fill_regions(ax, decided_regions(rows, x_key, y_key) if regions is None else regions)
    _legend_outside(ax)
    if title:
        ax.set_title(title, fontsize=13)
    return fig


def plain_log_ticks(axis) -> None:
    """Major ticks of a log axis at 1, 2, 3, 5, 10, 20, ..., written as numbers, not 10^1 and 10^2; no minor ones."""
    axis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 3.0, 5.0)))
    axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_locator(matplotlib.ticker.NullLocator())


#: regimes whose regions are shaded (the others -- undecided, model limit, failed -- stay white)
SHADED = ("TT", "PT", "TU")
SHADE_ALPHA = 0.16


def decided_regions(rows: list[dict], x_key: str, y_key: str) -> list[tuple[tuple, str]]:
    """The regions the cases of a grid (or of a search's rows) decide: analysis/regions.py, rows along
    the parameter with more distinct values. A point run more than once with different regimes
    (several starts) decides nothing."""
    from hpcves.analysis.regions import row_regions

    outcomes = {}
    for r in rows:
        point = (r[x_key], r[y_key])
        outcomes[point] = r["regime"] if outcomes.get(point, r["regime"]) == r["regime"] else "mixed"
    along_x = len({x for x, _ in outcomes}) >= len({y for _, y in outcomes})
    return row_regions(outcomes, rows_along_x=along_x)


def fill_regions(ax, regions, alpha: float = 2 * SHADE_ALPHA) -> list[str]:
    """Fill each region ((x0, x1, y0, y1), regime) of a shaded regime in its pale colour, behind
    everything; the regimes filled."""
    from matplotlib.patches import Rectangle

    filled = []
    for (x0, x1, y0, y1), regime in regions:
        if regime in SHADED:
            colour = pale(REGIME_STYLE[regime][0], alpha)
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, facecolor=colour, edgecolor=colour, linewidth=0.3,
                                   zorder=0))
            filled.append(regime)
    return filled


def pale(colour: str, alpha: float = 2 * SHADE_ALPHA) -> tuple:
    """``colour`` laid over white at ``alpha``, as an opaque colour: touching patches show no seams."""
    r, g, b = matplotlib.colors.to_rgb(colour)
    return (1 - alpha + alpha * r, 1 - alpha + alpha * g, 1 - alpha + alpha * b)


#: a log axis gets ticks at the swept values when there are at most this many
MAX_SWEEP_TICKS = 12


def _legend_outside(ax) -> None:
    """The legend beside the axes, where it can cover no point."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=11, frameon=False)


def period_figure(rows: list[dict], row_key: str, col_key: str, title: str = ""):
    """The period table as a figure: cells coloured by S x period (the 1/S law makes it flat),
    holding the period T +- its uncertainty and the S T the colour shows; other regimes named."""
    row_values = sorted({r[row_key] for r in rows})
    col_values = sorted({r[col_key] for r in rows})
    cells = {(r[row_key], r[col_key]): r for r in rows}
    fig = Figure(figsize=(1.6 * len(col_values) + 2.5, 0.8 * len(row_values) + 2), constrained_layout=True)
    ax = fig.subplots()
    scaled = np.full((len(row_values), len(col_values)), np.nan)
    texts = {}
    for i, rv in enumerate(row_values):
        for j, cv in enumerate(col_values):
            r = cells.get((rv, cv))
            if r is None:
                continue
            if r["regime"] in ("PT", "TU") and np.isfinite(r["period"]):
                scale = r["shear_rate"] if "shear_rate" in r else 1.0
                scaled[i, j] = r["period"] * scale
                error, dominant = accuracy.error_bar(r, "period")
                texts[i, j] = f"T = {r['period']:.4g}\n$\\pm${error:.1g} [{dominant}]\nS T = {scaled[i, j]:.3g}"
            else:
                texts[i, j] = r["regime"]
    image = ax.imshow(np.ma.masked_invalid(scaled), cmap="YlOrBr", aspect="auto", origin="lower")
    for (i, j), text in texts.items():              # white on the dark end of the colour scale
        dark = np.isfinite(scaled[i, j]) and image.norm(scaled[i, j]) > 0.6
        ax.text(j, i, text, ha="center", va="center", fontsize=9, color="white" if dark else "black")
    fig.colorbar(image, ax=ax, label="S T: the colour (the 1/S law makes it flat)")
    ax.set_xticks(range(len(col_values)), [f"{v:g}" for v in col_values])
    ax.set_yticks(range(len(row_values)), [f"{v:g}" for v in row_values])
    ax.set_xlabel(AXIS_LABELS.get(col_key, col_key))
    ax.set_ylabel(AXIS_LABELS.get(row_key, row_key))
    if title:
        ax.set_title(title)
    return fig


#: what a search runs along -> (its critical value's column, its symbol in a figure)
CRITICAL = {"shear_rate": ("S_C", "S$_C$"), "viscosity_ratio": ("lambda_C", r"$\lambda_C$")}


def mark_critical(ax, searches: list[dict], other_key: str, s_on_x: bool = True, along: str = "shear_rate") -> None:
    """On a phase diagram with S (``along``) on one axis: each search's bracket [low, high] as a bar at its
    ``other_key`` value, S_C (lambda_C) as a diamond, and the curve through the converged ones in order of
    ``other_key`` (rows of critical_shear.csv, critical_lambda.csv)."""
    def xy(s_values, others):
        return (s_values, others) if s_on_x else (others, s_values)

    column, symbol = CRITICAL[along]
    label, curve_label = f"{symbol} bracket", symbol
    runs, run = [], []                # the curve breaks where a search did not converge
    for r in sorted(searches, key=lambda r: r[other_key]):
        low, high = r["bracket_low"], r["bracket_high"]
        if np.isfinite(low) and np.isfinite(high):
            ax.plot(*xy([low, high], [r[other_key]] * 2), color="k", lw=3, solid_capstyle="butt", zorder=4,
                    label=label)
            label = None
        if np.isfinite(r[column]):
            run.append((r[column], r[other_key]))
        elif run:
            runs.append(run)
            run = []
    runs += [run] if run else []
    for run in runs:
        s_values, others = zip(*run)
        ax.plot(*xy(s_values, others), "D-", color="goldenrod", mfc="gold", mec="k", ms=9, lw=2, zorder=5,
                label=curve_label)
        curve_label = None
    if label is None or curve_label is None:
        _legend_outside(ax)


@matplotlib.rc_context({"font.size": 13})
def theta_curves(panels: list[tuple[str, list[tuple[float, np.ndarray, np.ndarray]]]], shear_times: float = 40.0):
    """theta(t) of several cases against the shear time S t, one panel per entry of ``panels``
    = (title, [(S, t, theta), ...]); a colour per S (log scale), the first ``shear_times``."""
    rates = sorted({s for _, curves in panels for s, _, _ in curves})
    cmap = matplotlib.colormaps["viridis"]
    norm = matplotlib.colors.LogNorm(min(rates), max(rates)) if len(rates) > 1 else None
    fig = Figure(figsize=(5.2 * len(panels) + 1.5, 4.4), constrained_layout=True)
    axes = fig.subplots(1, len(panels), squeeze=False, sharey=True)
    for ax, (title, curves) in zip(axes[0], panels):
        for s, t, theta in sorted(curves, key=lambda c: c[0]):
            shown = s * np.asarray(t) <= shear_times
            ax.plot(s * np.asarray(t)[shown], np.asarray(theta)[shown], lw=1.3,
                    color=cmap(norm(s)) if norm else "k", label=f"S = {s:g}")
        ax.set_xlabel("shear times $S t$")
        ax.set_title(title, fontsize=12)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(r"inclination $\theta$ [rad]")
    axes[0][-1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=10)
    return fig


def mark_boundaries(ax, lines: list[dict], x_key: str, y_key: str) -> None:
    """The located regime boundaries (rows of boundaries.csv) on a phase diagram: each polyline
    through its crossings, solid between decided cases, dashed where one side is undecided,
    failed or at the model's limit (blurry)."""
    by_line = {}
    for r in lines:
        by_line.setdefault(r["line"], []).append(r)
    labels = {}
    for points in by_line.values():
        points.sort(key=lambda r: r["order"])
        blurry = any(r["blurry"] for r in points)
        label = "boundary (blurry: one side undecided)" if blurry else "boundary"
        xs, ys = [r[x_key] for r in points], [r[y_key] for r in points]
        ax.plot(xs, ys, color="0.45" if blurry else "k", ls="--" if blurry else "-", lw=2.2, marker=".", ms=5,
                zorder=4, label=None if label in labels else label)
        labels[label] = True
    if labels:
        _legend_outside(ax)


#: a journal column: 8.6 cm (Phys. Rev., J. Fluid Mech. and Soft Matter columns are 8.3-8.9 cm), 8 pt type
PAPER_WIDTH = 3.4
PAPER_RC = {"font.size": 8, "axes.labelsize": 8, "axes.titlesize": 8, "legend.fontsize": 7, "xtick.labelsize": 7,
            "ytick.labelsize": 7, "axes.linewidth": 0.6, "xtick.major.width": 0.6, "ytick.major.width": 0.6,
            "xtick.minor.width": 0.4, "ytick.minor.width": 0.4}


def smoothed(line, logs=(False, False), rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A polyline through a boundary's crossings with its corners cut (Chaikin: each segment's points at
    1/4 and 3/4 replace its ends, ``rounds`` times; the ends stay), on the axes' scales (``logs``): the
    staircase of a refinement's cell edges drawn as the smooth curve it brackets. Every point of the
    result lies on a segment of the polyline's ``rounds``-fold cut, between neighbouring crossings."""
    points = np.array([[math.log(v) if log else v for v, log in zip(p, logs)] for p in line], dtype=float)
    for _ in range(rounds if len(points) > 2 else 0):
        a, b = points[:-1], points[1:]
        cut = np.empty((2 * len(a), 2))
        cut[0::2], cut[1::2] = 0.75 * a + 0.25 * b, 0.25 * a + 0.75 * b
        points = np.vstack([points[:1], cut, points[-1:]])
    return tuple(np.exp(points[:, k]) if log else points[:, k] for k, log in enumerate(logs))


def paper_diagram(rows: list[dict], x_key: str, y_key: str, regions, lines=(), brackets=(), markers: bool = False,
                  log_keys=(), title: str = ""):
    """A phase diagram for a paper, a journal column wide: the ``regions`` the cases decide
    (((x0, x1, y0, y1), regime): analysis/regions.py, refine.regions) filled, the boundaries
    (``lines``: polylines [(x, y), ...]) drawn through the white between them, a search's
    ``brackets`` (((x, y), (x, y)) segments: where its critical value lies) as bars, and the cases
    as small markers only with ``markers``. Nothing is drawn beyond the outermost cases.
    ``log_keys``: the parameters on a log axis. Vector graphics throughout: save it as PDF."""
    from matplotlib.patches import Patch

    with matplotlib.rc_context(PAPER_RC):
        fig = Figure(figsize=(PAPER_WIDTH, 0.8 * PAPER_WIDTH), constrained_layout=True)
        ax = fig.subplots()
        present = fill_regions(ax, regions)
        handles = [Patch(facecolor=pale(REGIME_STYLE[r][0]), edgecolor="none", label=REGIME_STYLE[r][2])
                   for r in SHADED if r in present]
        for k, line in enumerate(lines):
            xs, ys = smoothed(line, [key in log_keys for key in (x_key, y_key)])
            ax.plot(xs, ys, color="k", lw=0.9, zorder=3, label="boundary" if k == 0 else None)
        for k, ((xa, ya), (xb, yb)) in enumerate(brackets):
            ax.plot([xa, xb], [ya, yb], color="k", lw=0.6, zorder=3, marker="|" if ya == yb else "_", ms=3,
                    label="bracket of the critical value" if k == 0 else None)
        if markers:
            for regime, (colour, marker, label) in REGIME_STYLE.items():
                chosen = [r for r in rows if r["regime"] == regime]
                if chosen:
                    ax.scatter([r[x_key] for r in chosen], [r[y_key] for r in chosen], s=6, c=colour, marker=marker,
                               linewidths=0.3, edgecolors="k" if marker not in "xX" else None, zorder=4,
                               label=label)
        for axis, key in ((ax.xaxis, x_key), (ax.yaxis, y_key)):
            if key in log_keys:
                (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
                plain_log_ticks(axis)
        ax.update_datalim([(r[x_key], r[y_key]) for r in rows])        # the cases' extent, a little margin
        ax.margins(0.03)
        ax.autoscale_view()
        for axis, limits in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            if axis.get_scale() == "log" and math.log10(limits[1] / limits[0]) > 1.5:    # 1, 2, 5: room for them
                axis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
        ax.set_ylabel(AXIS_LABELS.get(y_key, y_key))
        line_handles, _ = ax.get_legend_handles_labels()
        ax.legend(handles=handles + line_handles, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3,
                  frameon=False, handlelength=1.2, columnspacing=1.0, borderaxespad=0.2)
        if title:
            fig.suptitle(title)
    return fig


def critical_shear_figure(searches: list[dict], x_key: str, title: str = "", along: str = "shear_rate"):
    """S_C (lambda_C: ``along`` = "viscosity_ratio") against one swept parameter: the bracket as an error
    bar, the critical value as a point; a search that did not bracket it is an arrow at the end of its range."""
    column, symbol = CRITICAL[along]
    fig = Figure(figsize=(7, 5), constrained_layout=True)
    ax = fig.subplots()
    for r in searches:
        x, low, high = r[x_key], r["bracket_low"], r["bracket_high"]
        if np.isfinite(r[column]):
            ax.errorbar([x], [r[column]], yerr=[[r[column] - low], [high - r[column]]], fmt="D", color="C0",
                        mec="k", ms=8, capsize=5, lw=2)
        elif np.isfinite(low) and np.isfinite(high):
            ax.plot([x, x], [low, high], color="C1", lw=3)
            ax.annotate(r["status"], (x, high), textcoords="offset points", xytext=(5, 0), fontsize=9)
        elif np.isfinite(low):
            ax.plot([x], [low], marker="^", color="C3", ms=11, mec="k")
            ax.annotate(f"{symbol} > {low:g}", (x, low), textcoords="offset points", xytext=(8, -4), fontsize=10)
        elif np.isfinite(high):
            ax.plot([x], [high], marker="v", color="C3", ms=11, mec="k")
            ax.annotate(f"{symbol} < {high:g}", (x, high), textcoords="offset points", xytext=(8, -4), fontsize=10)
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.yaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.margins(x=0.15, y=0.15)
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key), fontsize=13)
    ax.set_ylabel("critical shear rate $S_C$" if along == "shear_rate" else
                  r"critical viscosity ratio $\lambda_C$", fontsize=13)
    ax.grid(alpha=0.3, which="both")
    gaps = [r for r in searches if np.isfinite(r.get("bending_gap", math.nan))]
    if gaps:                                      # Delta E_b of the PT case at each bracket top, beside S_C
        twin = ax.twinx()
        xs = [r[x_key] for r in searches]
        dodge = 0.015 * (max(xs) - min(xs))           # beside its diamond, not on it
        twin.errorbar([r[x_key] + dodge for r in gaps], [r["bending_gap"] for r in gaps],
                      yerr=[np.nan_to_num(r["bending_gap_err"]) for r in gaps], fmt="o", color="tab:orange",
                      mec="k", ms=7, capsize=3, label=r"$\Delta E_b$ (right)")
        twin.set_ylabel(r"bending-energy gap $\Delta E_b$ at the bracket top", color="tab:orange", fontsize=12)
        twin.set_ylim(bottom=0.0, top=1.15 * max(r["bending_gap"] + np.nan_to_num(r["bending_gap_err"])
                                                  for r in gaps))
        handles = [matplotlib.lines.Line2D([], [], marker="D", ls="", color="C0", mec="k", label=f"{symbol} (left)"),
                   twin.get_legend_handles_labels()[0][0]]
        ax.legend(handles=handles, frameon=False, fontsize=10, loc="upper center")
    if title:
        ax.set_title(title, fontsize=13)
    return fig


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
