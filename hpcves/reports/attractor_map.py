"""Attractor maps: the runs of several starts over one parameter plane, point by point.

Each start is a campaign (or any list of regimes.csv rows) over the same plane; a [refine] campaign
splits cells at the same midpoints whatever it finds, so two starts share many points. At every point
run from more than one start, the runs are grouped into distinct attractors (analysis/attractors.py);
the map draws each shared point as a marker split between the starts' regimes, ringed where they
reached different attractors, and the summary counts the points by what the starts found.
"""
from __future__ import annotations

import math
from dataclasses import replace

from hpcves.analysis.accuracy import TUMBLING_ORBIT_SPREAD
from hpcves.analysis.attractors import Run, group
from hpcves.analysis.pattern import Topology
from hpcves.model.params import SWEEPABLE, parameter_of
from hpcves.reports.tables import markdown_table


def _bar(row: dict, name: str) -> float:
    parts = [row.get(f"{name}_err", math.nan), row.get(f"{name}_dt_err", math.nan), row.get(f"{name}_N_err", math.nan)]
    finite = [p for p in parts if math.isfinite(p)]
    return sum(finite) if finite else math.nan


def run_from_row(row: dict, start: str) -> Run:
    """An analysis Run from a regimes.csv row (its topology where the row has one). A tumbling run has no
    time-step bar (accuracy.py): its period is compared within TUMBLING_ORBIT_SPREAD, its mean inclination
    (an average over flips) not at all."""
    topology = None
    if math.isfinite(row.get("soft_domains", math.nan)):
        topology = Topology(int(row["soft_domains"]), int(row["domains_on_tips"]), bool(row["two_fold"]))
    theta_bar, period_bar = _bar(row, "theta_mean"), _bar(row, "period")
    if row["regime"] == "TU" and not math.isfinite(row.get("period_dt_err", math.nan)):
        theta_bar = math.inf
        if math.isfinite(row["period"]):
            period_bar = (period_bar if math.isfinite(period_bar) else 0.0) + TUMBLING_ORBIT_SPREAD * row["period"]
    return Run(start, row["regime"], topology, row["theta_mean"], theta_bar, row["period"], period_bar)


def last_runs(rows) -> dict:
    """{parameter point: its last run}, the run at the largest N where a refinement ran a point again."""
    last: dict = {}
    for r in rows:
        point = tuple(round(parameter_of(r, k), 9) for k in SWEEPABLE)
        if point not in last or r["N"] >= last[point]["N"]:
            last[point] = r
    return last


def compare(rows_by_start: dict, values: bool = True) -> list[dict]:
    """One entry per parameter point of any start: its parameters, the starts that ran it (their last
    run, at the largest N) and the attractors they reached. ``values`` False: attractors told apart by
    regime and pattern topology only, not by theta and the period (starts whose runs are not at quite
    the same parameters, such as a phase that does not have the mean psi_bar)."""
    runs: dict = {}
    for start, rows in rows_by_start.items():
        for key, r in last_runs(rows).items():
            runs.setdefault(key, {"parameters": {k: parameter_of(r, k) for k in SWEEPABLE},
                                  "rows": {}})["rows"][start] = r
    out = []
    for entry in runs.values():
        runs_here = [run_from_row(r, start) for start, r in entry["rows"].items()]
        if not values:
            runs_here = [replace(run, theta_err=math.inf, period_err=math.inf) for run in runs_here]
        found = group(runs_here)
        out.append({**entry["parameters"], "rows": entry["rows"], "attractors": found})
    return out


def summary(compared: list[dict], starts: tuple) -> str:
    """Markdown: the points run from every start, counted by what each start found and whether they
    reached one attractor or more."""
    shared = [c for c in compared if all(s in c["rows"] for s in starts)]
    counts: dict = {}
    for c in shared:
        decided = sum(len(a.runs) for a in c["attractors"])
        verdict = ("not comparable (a run not decided)" if decided < len(starts) else
                   "the same" if len(c["attractors"]) == 1 else f"{len(c['attractors'])} different")
        key = (tuple(c["rows"][s]["regime"] for s in starts), verdict)
        counts[key] = counts.get(key, 0) + 1
    body = [[" / ".join(regimes), verdict, str(count)]
            for (regimes, verdict), count in sorted(counts.items(), key=lambda kv: -kv[1])]
    head = (f"{len(shared)} points run from {' and '.join(starts)} ({len(compared) - len(shared)} more from one "
            "of them only).")
    if not body:
        return head
    return head + "\n\n" + markdown_table([" / ".join(starts), "attractors", "points"], body, left=(0, 1))


def figure(compared: list[dict], starts: tuple, x_key: str, y_key: str, title: str = ""):
    """Shared points as markers split between the regimes of the two ``starts`` (left: the first),
    ringed in black where they reached different attractors; points of one start only as small dots."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from hpcves.reports.diagrams import REGIME_STYLE

    first, second = starts
    colour = {regime: style[0] for regime, style in REGIME_STYLE.items()}
    fig = Figure(figsize=(10, 6), constrained_layout=True)
    ax = fig.subplots()
    differ = 0
    for c in compared:
        rows = c["rows"]
        x, y = c[x_key], c[y_key]
        if first in rows and second in rows:
            two = len(c["attractors"]) > 1
            differ += two
            ax.plot([x], [y], marker="o", markersize=9, fillstyle="left", linestyle="none",
                    markerfacecolor=colour.get(rows[first]["regime"], "w"),
                    markerfacecoloralt=colour.get(rows[second]["regime"], "w"),
                    markeredgecolor="k" if two else "0.6", markeredgewidth=2.0 if two else 0.5, zorder=3)
        else:
            start = first if first in rows else second
            ax.plot([x], [y], marker=".", markersize=5, linestyle="none", color=colour.get(rows[start]["regime"], "k"),
                    zorder=2)
    shown = {row["regime"] for c in compared for row in c["rows"].values()}
    handles = [Line2D([], [], marker="s", linestyle="none", markersize=9, color=colour[r], label=REGIME_STYLE[r][2])
               for r in REGIME_STYLE if r in ("TT", "PT", "TU", "undecided", "failed") or r in shown]
    handles += [Line2D([], [], marker="o", linestyle="none", markersize=9, fillstyle="left", markerfacecolor="w",
                       markerfacecoloralt="0.7", markeredgecolor="0.6", label=f"left: {first}, right: {second}"),
                Line2D([], [], marker="o", linestyle="none", markersize=9, markerfacecolor="w", markeredgecolor="k",
                       markeredgewidth=2.0, label=f"two attractors ({differ} point{'s' * (differ != 1)})"),
                Line2D([], [], marker=".", linestyle="none", color="0.4", label="run from one start only")]
    _finish(ax, handles, x_key, y_key, title, compared)
    return fig


#: a log axis with at most this many distinct values gets a tick at each of them
FEW_VALUES = 6


def _finish(ax, handles, x_key: str, y_key: str, title: str, compared=()) -> None:
    """The legend (``handles``) beside a map of the plane x_key x y_key, S on a log axis (ticked at the
    values run where they are few), labels, grid, title."""
    import matplotlib.ticker

    from hpcves.reports.diagrams import AXIS_LABELS, plain_log_ticks

    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=10)
    for key, axis, setter in ((x_key, ax.xaxis, ax.set_xscale), (y_key, ax.yaxis, ax.set_yscale)):
        if key == "shear_rate":
            setter("log")
            plain_log_ticks(axis)
            values = sorted({c[key] for c in compared})
            if 0 < len(values) <= FEW_VALUES:
                axis.set_major_locator(matplotlib.ticker.FixedLocator(values))
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(AXIS_LABELS.get(y_key, y_key))
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=13)


def attractors_figure(compared: list[dict], x_key: str, y_key: str, title: str = "", lines=None):
    """Every point by the attractors its runs reached: one regime colour where they reached one, a marker
    split between the first two (ringed in black, with the count where there are more) where they reached
    several; a point without a decided run is grey."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from hpcves.reports.diagrams import REGIME_STYLE

    colour = {regime: style[0] for regime, style in REGIME_STYLE.items()}
    fig = Figure(figsize=(10, 6), constrained_layout=True)
    ax = fig.subplots()
    several = undecided = 0
    for c in compared:
        x, y, found = c[x_key], c[y_key], c["attractors"]
        if not found:
            ax.plot([x], [y], marker="o", markersize=7, linestyle="none", color=colour["undecided"], zorder=2)
            continue
        two = len(found) > 1
        several += two
        ax.plot([x], [y], marker="o", markersize=10, fillstyle="left" if two else "full", linestyle="none",
                markerfacecolor=colour[found[0].regime],
                markerfacecoloralt=colour[found[1].regime] if two else colour[found[0].regime],
                markeredgecolor="k" if two else "0.6", markeredgewidth=2.0 if two else 0.5, zorder=3)
        if len(found) > 2:
            ax.annotate(str(len(found)), (x, y), xytext=(7, 5), textcoords="offset points", fontsize=9)
        if sum(len(a.runs) for a in found) < len(c["rows"]):
            undecided += 1
            ax.plot([x], [y], marker="o", markersize=3.5, linestyle="none", color=colour["undecided"],
                    markeredgecolor="k", markeredgewidth=0.4, zorder=4)
    handles = [Line2D([], [], marker="s", linestyle="none", markersize=9, color=colour[r], label=REGIME_STYLE[r][2])
               for r in ("TT", "PT", "TU")]
    handles += [Line2D([], [], marker="o", linestyle="none", markersize=7, color=colour["undecided"],
                       label="no run decided"),
                Line2D([], [], marker="o", linestyle="none", markersize=10, fillstyle="left", markerfacecolor="w",
                       markerfacecoloralt="0.7", markeredgecolor="k", markeredgewidth=2.0,
                       label=f"two or more attractors ({several} point{'s' * (several != 1)}):\nthe first two reached; "
                             "their number if more"),
                Line2D([], [], marker="o", linestyle="none", markersize=3.5, color=colour["undecided"],
                       markeredgecolor="k", markeredgewidth=0.4,
                       label=f"a run there not decided ({undecided} point{'s' * (undecided != 1)})")]
    if lines:                      # the borders a refinement of attractors traced (boundaries.csv rows)
        from hpcves.reports.diagrams import mark_boundaries

        mark_boundaries(ax, lines, x_key, y_key)
        drawn, _ = ax.get_legend_handles_labels()
        handles += drawn
    _finish(ax, handles, x_key, y_key, title)
    return fig


def hysteresis_figure(runs_by_label: dict, key: str, title: str = "", joins: dict | None = None):
    """The settled inclination (top) and, where any run has one, the period (bottom) against the chained
    key ``key``, one line per label (a start and a leg of a chain: up solid, down dashed) through its
    runs in chain order, starting from ``joins[label]`` (the run the leg turned from), each point's
    marker in its regime's style; error bars are the statistical plus time-step bars."""
    import numpy as np
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from hpcves.reports.diagrams import AXIS_LABELS, REGIME_STYLE, plain_log_ticks

    joins = joins or {}
    periodic = any(math.isfinite(r["period"]) for rows in runs_by_label.values() for r in rows)
    fig = Figure(figsize=(10, 7.5 if periodic else 4.5), constrained_layout=True)
    top, bottom = fig.subplots(2, 1, sharex=True) if periodic else (fig.subplots(), None)
    colours = {}
    for label, rows in runs_by_label.items():
        start = label.rsplit(" ", 2)[0] if label.endswith((" up", " down")) else label
        colour = colours.setdefault(start, f"C{len(colours)}")
        x = np.array([r[key] for r in rows])
        turn = joins.get(label)
        panels = ((top, "theta_mean"), (bottom, "period")) if periodic else ((top, "theta_mean"),)
        for ax, name in panels:
            y = np.array([r[name] for r in rows])
            err = np.array([_bar(r, name) for r in rows])
            line_x, line_y = (x, y) if turn is None else (np.insert(x, 0, turn[key]), np.insert(y, 0, turn[name]))
            ax.plot(line_x, line_y, color=colour, linestyle="--" if label.endswith(" down") else "-",
                    linewidth=1.2, zorder=2)
            for xi, yi, ei, r in zip(x, y, err, rows):
                if not np.isfinite(yi):
                    continue
                style = REGIME_STYLE.get(r["regime"], REGIME_STYLE["undecided"])
                ax.errorbar([xi], [yi], yerr=[ei] if np.isfinite(ei) else None, marker=style[1], color=colour,
                            markerfacecolor=style[0], markeredgecolor=colour, markersize=8, linestyle="none",
                            zorder=3)
    top.set_ylabel(r"mean inclination $\theta$ (rad)")
    lowest = bottom if periodic else top
    if periodic:
        bottom.set_ylabel("period of $\\theta$")
    lowest.set_xlabel(AXIS_LABELS.get(key, key))
    if key == "shear_rate":
        lowest.set_xscale("log")
        plain_log_ticks(lowest.xaxis)
    for ax in (top, bottom) if periodic else (top,):
        ax.grid(alpha=0.3)
    handles = [Line2D([], [], color=c, label=s or "runs") for s, c in colours.items()]
    handles += [Line2D([], [], color="0.3", linestyle="-", label="up"),
                Line2D([], [], color="0.3", linestyle="--", label="down")]
    handles += [Line2D([], [], marker=REGIME_STYLE[r][1], linestyle="none", markersize=8,
                       markerfacecolor=REGIME_STYLE[r][0],
                       markeredgecolor="0.3", label=REGIME_STYLE[r][2]) for r in ("TT", "PT", "TU")]
    top.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=10)
    if title:
        top.set_title(title, fontsize=13)
    return fig
