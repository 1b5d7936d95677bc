"""Figures of a campaign over its parameters (matplotlib, no display needed).

:func:`phase_diagram` (every case drawn over the regions its cases decide),
:func:`paper_diagram` (the figure for a paper: regions, boundaries, a journal
column wide), :func:`period_figure`, :func:`critical_shear_figure` and what
they draw on (the regimes' styles, the parameters' axis labels, the critical
values and traced boundaries). One case's figures are in
:mod:`hpcves.reports.case_figures`.
"""
from __future__ import annotations

import math

import matplotlib
import matplotlib.cm
import matplotlib.colors
import matplotlib.lines
import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from hpcves.analysis import accuracy
from hpcves.analysis.search import centre_only
from hpcves.model.params import PARAMETER_NAMES

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
    log_axes(ax, rows, (x_key, y_key), log_keys)
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(AXIS_LABELS.get(y_key, y_key))
    ax.grid(alpha=0.3)
    fill_regions(ax, decided_regions(rows, x_key, y_key) if regions is None else regions)
    _legend_outside(ax)
    if title:
        ax.set_title(title, fontsize=13)
    return fig


def log_axes(ax, rows: list[dict], keys: tuple, log_keys=None) -> tuple[bool, ...]:
    """Put the x (and y) axis of ``keys`` on a log scale where ``log_keys`` names it (default: the shear
    rate and the viscosity ratio, and any other swept over a factor of 20 or more); ticks at the swept
    values where they are few and no ``log_keys`` were given, else at 1, 2, 3, 5, 10, ... Which are log."""
    logs = []
    for axis, key in zip((ax.xaxis, ax.yaxis), keys):
        values = sorted({r[key] for r in rows})
        log = (key in log_keys) if log_keys is not None else _log_scale(values, key)
        if log:
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
            if log_keys is None and len(values) <= MAX_SWEEP_TICKS:   # ticks at the swept values
                axis.set_ticks(values, [f"{v:g}" for v in values])
            else:
                plain_log_ticks(axis)
            axis.set_minor_locator(matplotlib.ticker.NullLocator())
        logs.append(log)
    return tuple(logs)


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
    bar, the best estimate inside it as a point (hollow where it is only the bracket's centre); a search
    that did not bracket it is an arrow at the end of its range."""
    column, symbol = CRITICAL[along]
    fig = Figure(figsize=(7, 5), constrained_layout=True)
    ax = fig.subplots()
    for r in searches:
        x, low, high = r[x_key], r["bracket_low"], r["bracket_high"]
        if np.isfinite(r[column]):
            centre = centre_only(r.get(f"{column}_from", ""))
            ax.errorbar([x], [r[column]], yerr=[[r[column] - low], [high - r[column]]], fmt="D", color="C0",
                        mec="k", ms=8, capsize=5, lw=2, mfc="white" if centre else "C0")
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
    handles = [matplotlib.lines.Line2D([], [], marker="D", ls="", color="C0", mec="k",
                                       label=f"{symbol}: estimate, bar: bracket" + (" (left)" if gaps else ""))]
    if any(centre_only(r.get(f"{column}_from", "")) for r in searches if np.isfinite(r[column])):
        handles.append(matplotlib.lines.Line2D([], [], marker="D", ls="", color="C0", mec="k", mfc="white",
                                               label="hollow: the bracket's centre (no estimate)"))
    if gaps:
        handles.append(twin.get_legend_handles_labels()[0][0])
    if any(np.isfinite(r[column]) for r in searches):
        ax.legend(handles=handles, frameon=False, fontsize=10, loc="upper center")
    if title:
        ax.set_title(title, fontsize=13)
    return fig


#: the rheology columns a figure draws: (column, axis label)
STRESS_LABELS = {"intrinsic_viscosity": r"intrinsic viscosity $[\eta]$",
                 "normal_stress_coefficient": r"normal-stress coefficient $N_1$"}


@matplotlib.rc_context({"font.size": 14})
def stress_diagram(rows: list[dict], x_key: str, y_key: str, quantity: str = "intrinsic_viscosity",
                   title: str = "", log_keys=None):
    """The settled mean of a rheology column (``quantity``) over two swept parameters: a colour map
    interpolated between the cases that have it (linear on triangles, in the axes' own scales) with
    the cases on it as white markers shaped by regime (those without the value grey)."""
    import matplotlib.tri

    fig = Figure(figsize=(10, 6), constrained_layout=True)
    ax = fig.subplots()
    logs = log_axes(ax, rows, (x_key, y_key), log_keys)
    have = [r for r in rows if math.isfinite(r.get(quantity, math.nan))]
    values = np.array([r[quantity] for r in have])
    mapped = None
    if have:
        x = np.array([r[x_key] for r in have], dtype=float)
        y = np.array([r[y_key] for r in have], dtype=float)
        u, v = (np.log(x) if logs[0] else x), (np.log(y) if logs[1] else y)
        levels = np.linspace(values.min(), values.max(), 13) if np.ptp(values) > 0 else None
        try:
            if levels is None or len(have) < 3:
                raise ValueError("too few values for a map")
            mesh = matplotlib.tri.Triangulation(u, v)
            mapped = ax.tricontourf(matplotlib.tri.Triangulation(x, y, mesh.triangles), values, levels=levels,
                                    cmap="viridis", zorder=0)
        except (ValueError, RuntimeError):             # collinear or too few points: the markers alone
            mapped = ax.scatter(x, y, c=values, cmap="viridis", s=400, marker="s", zorder=0)
    for regime, (colour, marker, label) in REGIME_STYLE.items():
        chosen = [r for r in rows if r["regime"] == regime]
        if not chosen:
            continue
        shown = [math.isfinite(r.get(quantity, math.nan)) for r in chosen]
        ax.scatter([r[x_key] for r in chosen], [r[y_key] for r in chosen], s=90, marker=marker,
                   c=["white" if s else "0.55" for s in shown], edgecolors="k" if marker not in "xX" else None,
                   linewidths=0.8, label=f"{label} ({len(chosen)})", zorder=3, clip_on=False)
    if len(have) <= 60:                                # few enough to read each value off the figure
        for r in have:
            ax.annotate(f"{r[quantity]:.4g}", (r[x_key], r[y_key]), textcoords="offset points", xytext=(0, 10),
                        ha="center", fontsize=9, zorder=4,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7})
    ax.use_sticky_edges = False                        # the filled map would pin the limits to the cases
    ax.margins(0.08)
    if mapped is not None:
        bar = fig.colorbar(mapped, ax=ax, location="left", pad=0.02)
        bar.set_label(STRESS_LABELS.get(quantity, quantity))
        bar.ax.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(7))
        bar.ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%.4g"))
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(AXIS_LABELS.get(y_key, y_key))
    _legend_outside(ax)
    shown_title = STRESS_LABELS.get(quantity, quantity) + (f"; {title}" if title else "")
    if not have:
        shown_title += " (no case has it)"
    ax.set_title(shown_title, fontsize=13)
    return fig


@matplotlib.rc_context({"font.size": 14})
def stress_curves(rows: list[dict], x_key: str, title: str = "", log_keys=None):
    """[eta] and N1 (settled means) against one swept parameter, a panel each: markers by regime with
    their whole error bars (statistical + time step + grid, accuracy.error_bar), joined in order."""
    fig = Figure(figsize=(9, 7), constrained_layout=True)
    axes = fig.subplots(2, 1, sharex=True)
    for ax, quantity in zip(axes, STRESS_LABELS):
        have = sorted((r for r in rows if math.isfinite(r.get(quantity, math.nan))), key=lambda r: r[x_key])
        ax.plot([r[x_key] for r in have], [r[quantity] for r in have], color="0.6", lw=1, zorder=1)
        for regime, (colour, marker, label) in REGIME_STYLE.items():
            chosen = [r for r in have if r["regime"] == regime]
            if chosen:
                bars = [accuracy.error_bar(r, quantity)[0] for r in chosen]
                ax.errorbar([r[x_key] for r in chosen], [r[quantity] for r in chosen], yerr=bars, fmt=marker,
                            color=colour, mec="k", mew=0.6, ms=8, capsize=3, label=f"{label} ({len(chosen)})",
                            zorder=3)
        ax.set_ylabel(STRESS_LABELS[quantity])
        ax.grid(alpha=0.3)
        values = [r[quantity] for r in have]
        if values and min(values) < 0 < max(values):      # a sign change: where it happens matters
            ax.axhline(0.0, color="k", lw=0.6)
    log_axes(axes[1], rows, (x_key,), log_keys)
    axes[1].set_xlabel(AXIS_LABELS.get(x_key, x_key))
    _legend_outside(axes[0])
    if title:
        axes[0].set_title(title, fontsize=13)
    return fig
